//! The controller's window on the joint reference: a ring of `REF_RING`·`REF_CHUNK` rows that the
//! supervisor's chunks are copied into (the rule that keeps it sufficient is in
//! `deltaloop_transport::ipc`). Allocated and touched once, before the loop: filing and finding a
//! row never allocates, locks or faults a page.

use deltaloop_transport::ipc::{REF_CHUNK, REF_RING};
use deltaloop_transport::wire::RefSample;

/// Rows of the joint reference by tick, the row of tick k in slot k mod [`RefRing::LEN`].
pub struct RefRing {
    slots: Box<[RefSample]>,
}

/// The tick of a slot that holds no row yet: no run reaches it (tick 0 cannot mark empty slots,
/// it is a real tick).
const EMPTY: u64 = u64::MAX;

impl RefRing {
    /// Rows the ring holds: `REF_RING` chunks of `REF_CHUNK` rows.
    pub const LEN: usize = REF_RING * REF_CHUNK;

    /// An empty ring of [`Self::LEN`] rows, every slot written (so every page is touched now).
    pub fn new() -> Self {
        let empty = RefSample {
            tick: EMPTY,
            ..RefSample::default()
        };
        Self {
            slots: vec![empty; Self::LEN].into_boxed_slice(),
        }
    }

    /// Files `row` under its tick, replacing the row `LEN` ticks before it.
    pub fn put(&mut self, row: &RefSample) {
        self.slots[Self::slot(row.tick)] = *row;
    }

    /// The row of tick `k`, None if it has not arrived (or was already replaced).
    pub fn get(&self, k: u64) -> Option<&RefSample> {
        let row = &self.slots[Self::slot(k)];
        (row.tick == k && k != EMPTY).then_some(row)
    }

    fn slot(k: u64) -> usize {
        (k % Self::LEN as u64) as usize
    }
}

impl Default for RefRing {
    fn default() -> Self {
        Self::new()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn row(tick: u64) -> RefSample {
        RefSample {
            tick,
            q: [tick as f64, 0.0, 0.0],
            ..RefSample::default()
        }
    }

    /// A fresh ring holds nothing, not even tick 0 (its slots are zero but for the tick).
    #[test]
    fn a_fresh_ring_holds_no_tick() {
        let ring = RefRing::new();
        for k in [0, 1, RefRing::LEN as u64 - 1, RefRing::LEN as u64, u64::MAX] {
            assert!(ring.get(k).is_none(), "tick {k}");
        }
    }

    /// A row is found by its own tick, wherever in the stream it came.
    #[test]
    fn rows_are_found_by_their_tick() {
        let mut ring = RefRing::new();
        for k in [0, 1, 4095, 4096, 70_000] {
            ring.put(&row(k));
        }
        for k in [0, 1, 4095, 4096, 70_000] {
            assert_eq!(ring.get(k), Some(&row(k)));
        }
        assert!(ring.get(2).is_none());
    }

    /// Tick k + LEN replaces tick k in the same slot: the old tick is gone, not misread.
    #[test]
    fn a_row_one_ring_later_replaces_the_old_one() {
        let mut ring = RefRing::new();
        let len = RefRing::LEN as u64;
        ring.put(&row(5));
        assert!(ring.get(5 + len).is_none());
        ring.put(&row(5 + len));
        assert_eq!(ring.get(5 + len), Some(&row(5 + len)));
        assert!(ring.get(5).is_none());
    }

    /// The ring spans exactly `REF_RING` chunks: a whole run streamed through it chunk by chunk
    /// keeps the last `REF_RING` chunks and nothing older.
    #[test]
    fn the_ring_keeps_the_last_ref_ring_chunks() {
        let mut ring = RefRing::new();
        let (c, chunks) = (REF_CHUNK as u64, REF_RING as u64 + 3);
        for k in 0..chunks * c {
            ring.put(&row(k));
        }
        let oldest_kept = (chunks - REF_RING as u64) * c;
        assert!(ring.get(oldest_kept - 1).is_none());
        for k in oldest_kept..chunks * c {
            assert_eq!(ring.get(k).map(|r| r.tick), Some(k));
        }
    }
}
