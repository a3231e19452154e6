//! The supervisor's end of the joint reference: sends it to the controller in chunks of
//! `REF_CHUNK` rows, never more than the controller's ring of `REF_RING` chunks can hold (the
//! rule is in `deltaloop_transport::ipc`). Rows are computed as each chunk is written, so neither
//! the supervisor, nor shared memory, nor the controller holds the whole run.

use anyhow::Result;
use deltaloop_study::reference::JointReference;
use deltaloop_transport::ipc::{self, REF_CHUNK, REF_RING, RefOut};
use deltaloop_transport::wire::RefSample;

/// Chunks of a reference of `total_rows` rows: ⌈total / `REF_CHUNK`⌉.
pub fn chunk_count(total_rows: u64) -> u64 {
    total_rows.div_ceil(REF_CHUNK as u64)
}

/// The ticks chunk `c` holds: [c·C, min((c + 1)·C, total)).
pub fn chunk_ticks(c: u64, total_rows: u64) -> std::ops::Range<u64> {
    let c_len = REF_CHUNK as u64;
    (c * c_len).min(total_rows)..((c + 1) * c_len).min(total_rows)
}

/// How many chunks (0..this) the supervisor may have sent, given the newest tick the controller
/// has answered (None: none yet, before START), how many chunks it may be ahead (`lead`, at
/// most `REF_RING`) and how many rows past its state's tick the controller reads (`lookahead`
/// A: a compensated law at tick k reads rows up to k + A; 0 otherwise, A < `REF_CHUNK`). Chunk
/// c < lead may go at once; chunk c ≥ lead once a + 1 + A ≥ (c − lead + 1)·C, i.e.
/// c < ⌊(a + 1 + A)/C⌋ + lead. With A > 0 the lead is at most `REF_RING` − 1: the chunk of the
/// next tick the controller answers may then be one behind the chunk of the rows it reads, and
/// stays in the ring.
pub fn chunks_allowed(answered: Option<u64>, total_rows: u64, lead: u64, lookahead: u64) -> u64 {
    let ring = REF_RING as u64 - u64::from(lookahead > 0);
    let passed = answered.map_or(0, |a| {
        a.saturating_add(1).saturating_add(lookahead) / REF_CHUNK as u64
    });
    passed
        .saturating_add(lead.min(ring))
        .min(chunk_count(total_rows))
}

/// Chunks ahead in lockstep: one. The loop can then be at most one chunk (4096 ticks) past the
/// last reply the supervisor has received, half its observers' 8192-sample queues, so a
/// supervisor slower than the loop holds the loop back instead of losing samples (regression: a
/// debug-build supervisor under load fell so far behind a lockstep loop with no notifications
/// that the controller ran out of reference). The price is a wait of one supervisor poll at each
/// chunk boundary. Realtime keeps the whole ring (`REF_RING`): there the loop must never wait.
pub const LOCKSTEP_LEAD_CHUNKS: u64 = 1;

/// The reference publisher and how far it has got.
pub struct ReferenceFeed {
    publisher: RefOut,
    /// The next chunk to send (= chunks sent so far).
    next: u64,
    /// Rows of the reference, N + 2.
    total_rows: u64,
    /// Chunks the feed may be ahead of the controller's last answer.
    lead: u64,
    /// Rows past its state's tick the controller reads.
    lookahead: u64,
}

impl ReferenceFeed {
    /// Opens the reference publisher on the supervisor's node.
    pub fn create(
        node: &ipc::Node<ipc::Svc>,
        run_id: &str,
        total_rows: usize,
        lead: u64,
        lookahead: u64,
    ) -> Result<Self> {
        Ok(Self {
            publisher: ipc::reference_publisher(node, run_id)?,
            next: 0,
            total_rows: total_rows as u64,
            lead,
            lookahead,
        })
    }

    /// Sends chunks 0..min(lead, chunks) (before START).
    pub fn send_initial(&mut self, reference: &JointReference) -> Result<()> {
        self.send_up_to(
            reference,
            chunks_allowed(None, self.total_rows, self.lead, self.lookahead),
        )
    }

    /// Sends every chunk the rule allows now that the controller has answered tick `answered`.
    pub fn feed(&mut self, reference: &JointReference, answered: u64) -> Result<()> {
        self.send_up_to(
            reference,
            chunks_allowed(Some(answered), self.total_rows, self.lead, self.lookahead),
        )
    }

    /// Chunks sent so far.
    pub fn sent(&self) -> u64 {
        self.next
    }

    /// All chunks of the reference.
    pub fn chunks(&self) -> u64 {
        chunk_count(self.total_rows)
    }

    /// Sends chunks `next..end` in order.
    fn send_up_to(&mut self, reference: &JointReference, end: u64) -> Result<()> {
        while self.next < end {
            self.send_chunk(reference, self.next)?;
            self.next += 1;
        }
        Ok(())
    }

    /// Writes chunk `c`'s rows, each stamped with its tick, straight into shared memory and sends
    /// it.
    fn send_chunk(&self, reference: &JointReference, c: u64) -> Result<()> {
        let ticks = chunk_ticks(c, self.total_rows);
        // The first row that fails its check ends the run before the loop reaches it (chunks
        // go out ahead of the loop); its sample carries the end point meanwhile.
        let mut failed = None;
        self.publisher
            .send_chunk((ticks.end - ticks.start) as usize, &mut |i| {
                let tick = ticks.start + i as u64;
                let j = match reference.try_row(tick as usize) {
                    Ok(row) => row.joint,
                    Err(e) => {
                        failed.get_or_insert((tick, e));
                        reference.row(tick as usize).joint
                    }
                };
                RefSample {
                    tick,
                    q: j.q.into(),
                    qd: j.qd.into(),
                    qdd: j.qdd.into(),
                }
            })
            .map_err(|e| anyhow::anyhow!("{e} (reference chunk {c})"))?;
        match failed {
            Some((tick, e)) => anyhow::bail!("the reference at tick {tick}: {e}"),
            None => Ok(()),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const C: u64 = REF_CHUNK as u64;
    const R: u64 = REF_RING as u64;

    /// Chunks tile the ticks 0..total exactly, the last one short when total is not a multiple.
    #[test]
    fn chunks_tile_the_reference_with_a_short_last_one() {
        for total in [1, C - 1, C, C + 1, 3 * C + 7, 40 * C] {
            let n = chunk_count(total);
            let mut next = 0;
            for c in 0..n {
                let t = chunk_ticks(c, total);
                assert_eq!(t.start, next, "total {total}, chunk {c}");
                assert!(!t.is_empty() && t.end - t.start <= C);
                next = t.end;
            }
            assert_eq!(next, total, "total {total}");
        }
        assert_eq!(chunk_ticks(3, 3 * C + 7), 3 * C..3 * C + 7);
        assert_eq!(chunk_count(0), 0);
    }

    /// Before START, and after tick 0, the first `REF_RING` chunks may go, or all if fewer.
    #[test]
    fn the_first_ring_goes_before_start() {
        assert_eq!(chunks_allowed(None, 100 * C, R, 0), R);
        assert_eq!(chunks_allowed(Some(0), 100 * C, R, 0), R);
        assert_eq!(chunks_allowed(None, 3 * C + 7, R, 0), 4);
        assert_eq!(chunks_allowed(Some(0), 3 * C + 7, R, 0), 4);
        assert_eq!(chunks_allowed(None, 1, R, 0), 1);
    }

    /// Chunk `REF_RING` (which overwrites chunk 0) goes only once the last tick of chunk 0 was
    /// answered, and so on, one chunk per chunk passed.
    #[test]
    fn a_chunk_goes_once_the_one_it_overwrites_is_passed() {
        let total = 100 * C;
        assert_eq!(chunks_allowed(Some(C - 2), total, R, 0), R);
        assert_eq!(chunks_allowed(Some(C - 1), total, R, 0), R + 1);
        assert_eq!(chunks_allowed(Some(2 * C - 2), total, R, 0), R + 1);
        assert_eq!(chunks_allowed(Some(2 * C - 1), total, R, 0), R + 2);
    }

    /// A jump of many ticks (skipped replies, a slow observer) releases every chunk it passed at
    /// once, never beyond the end; absurd ticks saturate.
    #[test]
    fn a_jump_releases_many_chunks_but_never_past_the_end() {
        let total = 100 * C + 5;
        assert_eq!(chunks_allowed(Some(50 * C + 3), total, R, 0), 50 + R);
        assert_eq!(chunks_allowed(Some(total - 1), total, R, 0), 101);
        assert_eq!(chunks_allowed(Some(u64::MAX), total, R, 0), 101);
    }

    /// The rule never lets the supervisor get more than `REF_RING` chunks ahead of the chunk the
    /// controller is in, and never holds back the chunk of the next tick the controller needs.
    #[test]
    fn the_lockstep_lead_keeps_the_loop_within_one_chunk_of_the_last_answer() {
        let total = 100 * C;
        let l = LOCKSTEP_LEAD_CHUNKS;
        assert_eq!(chunks_allowed(None, total, l, 0), 1);
        // Answered up to a: the controller can reach at most tick a + C (then it needs chunk
        // ⌊(a + 1)/C⌋ + 1, not yet sent): one chunk past the answer, half the observers' queues.
        for a in [0, C - 2, C - 1, 7 * C + 5, total - 2] {
            let first_missing_row = chunks_allowed(Some(a), total, l, 0) * C;
            assert!(
                first_missing_row > a + 1 && first_missing_row <= a + 1 + C,
                "{a}"
            );
            assert!(first_missing_row - (a + 1) <= ipc::OBSERVER_BUFFER as u64 / 2);
        }
        // Never more than the ring, whatever lead is asked for.
        assert_eq!(chunks_allowed(None, total, 1000, 0), R);
    }

    #[test]
    fn the_rule_keeps_the_ring_sufficient_and_unoverrun() {
        let total = 37 * C + 11;
        // Without a look-ahead, and with a compensated law's (one tick, eight, most of a chunk).
        for lookahead in [0, 2, 9, C - 1] {
            for lead in [LOCKSTEP_LEAD_CHUNKS, R] {
                for a in (0..total).step_by(97).chain([
                    C - 1,
                    C,
                    C - 1 - lookahead,
                    total - 2,
                    total - 1,
                ]) {
                    let allowed = chunks_allowed(Some(a), total, lead, lookahead);
                    // The rows the controller reads next: ticks a + 1 ..= a + 1 + A.
                    let needed = (a + 1 + lookahead).min(total - 1) / C;
                    assert!(
                        allowed > needed,
                        "answered {a}, A {lookahead}: {needed} held"
                    );
                    // Chunk `allowed − 1` overwrites chunk `allowed − 1 − R`, whose ticks must
                    // all be ≤ a (the controller answers only ticks after a).
                    if allowed > R {
                        let dead = chunk_ticks(allowed - 1 - R, total);
                        assert!(dead.end <= a + 1, "answered {a}, A {lookahead}: live chunk");
                    }
                }
            }
        }
    }
}
