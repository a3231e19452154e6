//! How the far host's clock maps onto this one.

use deltaloop_transport::wire::StateMsg;

/// The offset from the far host's clock to this one, ns: the smallest of (arrival here −
/// publication there) over the last one to two blocks of [`OFFSET_BLOCK`] states, that is the
/// clocks' offset plus the quickest recent trip. A windowed minimum, so that it follows the two
/// clocks' drift over a long run; O(1) per state, no allocation.
#[derive(Clone, Copy, Debug)]
pub struct Offset {
    /// The minimum of the block being filled, and of the one before it.
    current: i64,
    previous: i64,
    /// States in the current block.
    n: u32,
}

/// States per block of the [`Offset`] window (0.3–0.6 s at 3.3 kHz).
pub const OFFSET_BLOCK: u32 = 1024;

impl Default for Offset {
    fn default() -> Self {
        Self {
            current: i64::MAX,
            previous: i64::MAX,
            n: 0,
        }
    }
}

impl Offset {
    /// Takes one state's (arrival − publication) and returns the offset in force.
    pub fn add(&mut self, seen: i64) -> i64 {
        self.current = self.current.min(seen);
        self.n += 1;
        let offset = self.current.min(self.previous);
        if self.n == OFFSET_BLOCK {
            (self.previous, self.current, self.n) = (self.current, i64::MAX, 0);
        }
        offset
    }
}

impl Offset {
    /// State `s`, arrived `now` (ns, this host's clock), with its stamps moved onto this clock:
    /// its deadline and wake by the offset in force (the quickest recent states', not its own: a
    /// state held up on the way keeps its deadline, and is late, instead of moving every later
    /// deadline by its delay), its publication as its arrival here.
    pub fn restamp(&mut self, s: &mut StateMsg, now: u64) {
        let offset = self.add(now.wrapping_sub(s.t_publish_ns) as i64);
        let shift = |t: u64| {
            if t == 0 {
                0
            } else {
                t.wrapping_add(offset as u64)
            }
        };
        (s.t_deadline_ns, s.t_wake_ns) = (shift(s.t_deadline_ns), shift(s.t_wake_ns));
        s.t_publish_ns = now;
    }
}
