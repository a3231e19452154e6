//! Replies across the link, each datagram carrying the [`COPIES`] − 1 replies before it too, so
//! an isolated lost datagram costs the plant a late reply, never the record: the plant's host
//! still learns every state the controller answered, and the run replays byte for byte. (Without
//! it, a reply lost on the wire left a state the far controller had taken into its history
//! recorded as unanswered, and the replay's controller, given only answered states, differed.)
//!
//! Wire: the payload of a [`Kind::Torque`](crate::frame::Kind) datagram is 1..=[`COPIES`]
//! entries, newest first, each a `TorqueMsg` and the far side's residence (u64, ns: state in to
//! reply out, on the far host's clock).

use crate::bytes::{self, bytes_of};
use deltaloop_transport::wire::TorqueMsg;

/// Replies per datagram: the newest and the two before it.
pub const COPIES: usize = 3;
/// Bytes of one entry: a `TorqueMsg` and its residence.
pub const ENTRY: usize = size_of::<TorqueMsg>() + 8;

/// Whether `n` payload bytes are a whole number of entries, 1..=[`COPIES`].
pub fn valid_len(n: usize) -> bool {
    n.is_multiple_of(ENTRY) && (1..=COPIES).contains(&(n / ENTRY))
}

/// The far side's last replies and the payload that carries them (pre-allocated).
pub struct Outbox {
    buf: [u8; COPIES * ENTRY],
    len: usize,
}

impl Default for Outbox {
    fn default() -> Self {
        Self {
            buf: [0; COPIES * ENTRY],
            len: 0,
        }
    }
}

impl Outbox {
    /// Puts reply `t` (with its `residence_ns`) in front of the last ones; the payload to send.
    pub fn push(&mut self, t: &TorqueMsg, residence_ns: u64) -> &[u8] {
        self.buf.copy_within(0..(COPIES - 1) * ENTRY, ENTRY);
        self.buf[..ENTRY - 8].copy_from_slice(bytes_of(t));
        self.buf[ENTRY - 8..ENTRY].copy_from_slice(&residence_ns.to_ne_bytes());
        self.len = (self.len + ENTRY).min(COPIES * ENTRY);
        self.payload()
    }

    /// The payload of the last push (empty before any).
    pub fn payload(&self) -> &[u8] {
        &self.buf[..self.len]
    }

    /// The newest reply's tick.
    pub fn newest_tick(&self) -> Option<u64> {
        entry(self.payload(), 0).map(|(t, _)| t.tick)
    }
}

/// Entry `i` of a payload (0: the newest).
fn entry(p: &[u8], i: usize) -> Option<(TorqueMsg, u64)> {
    let e = p.get(i * ENTRY..(i + 1) * ENTRY)?;
    let (msg, res) = e.split_at(ENTRY - 8);
    Some((bytes::read::<TorqueMsg>(msg)?, bytes::read::<u64>(res)?))
}

/// Ticks the near side remembers having republished.
const SEEN: usize = 256;

/// The near side's record of the replies it republished, to take each once.
pub struct Inbox {
    /// tick + 1 at slot tick % SEEN (0: empty).
    seen: [u64; SEEN],
    /// Replies taken from an older copy (their own datagram was lost or overtaken).
    pub recovered: u64,
    /// Replies for a state not yet sent, left out (protocol §8: a future tick is ignored).
    pub future: u64,
}

impl Default for Inbox {
    fn default() -> Self {
        Self {
            seen: [0; SEEN],
            recovered: 0,
            future: 0,
        }
    }
}

impl Inbox {
    /// The replies of payload `p` not taken before, oldest first, each once; `f` gets each with
    /// its residence. A reply for a tick past `newest_sent` (the newest state sent, None before
    /// the first) answers nothing and is left out before it is remembered, so it can never pass
    /// for, or shadow, the honest reply of that tick when it comes.
    pub fn take(&mut self, p: &[u8], newest_sent: Option<u64>, mut f: impl FnMut(TorqueMsg, u64)) {
        let n = p.len() / ENTRY;
        for i in (0..n).rev() {
            let Some((t, residence)) = entry(p, i) else {
                continue;
            };
            if newest_sent.is_none_or(|k| t.tick > k) {
                self.future += 1;
                continue;
            }
            let slot = &mut self.seen[(t.tick % SEEN as u64) as usize];
            if *slot == t.tick.wrapping_add(1) {
                continue;
            }
            *slot = t.tick.wrapping_add(1);
            if i > 0 {
                self.recovered += 1;
            }
            f(t, residence);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn reply(tick: u64) -> TorqueMsg {
        TorqueMsg {
            tick,
            tau: [tick as f64; 3],
            ..Default::default()
        }
    }

    /// Every reply is taken once, in tick order, whichever datagrams are lost.
    #[test]
    fn a_lost_datagram_is_recovered_from_the_next_and_nothing_is_taken_twice() {
        let mut out = Outbox::default();
        let mut inbox = Inbox::default();
        let mut got = Vec::new();
        for k in 0..10u64 {
            let p = out.push(&reply(k), 100 + k).to_vec();
            assert!(valid_len(p.len()));
            assert_eq!(out.newest_tick(), Some(k));
            // Datagrams 3 and 6, 7 are lost (two in a row is still within COPIES − 1).
            if ![3, 6, 7].contains(&k) {
                inbox.take(&p, Some(k), |t, res| got.push((t.tick, res, t.tau[0])));
            }
        }
        let want: Vec<_> = (0..10u64).map(|k| (k, 100 + k, k as f64)).collect();
        assert_eq!(got, want);
        assert_eq!(inbox.recovered, 3);
    }

    #[test]
    fn three_lost_in_a_row_lose_the_oldest_only() {
        let mut out = Outbox::default();
        let mut inbox = Inbox::default();
        let mut got = Vec::new();
        for k in 0..8u64 {
            let p = out.push(&reply(k), 0).to_vec();
            if !(2..=4).contains(&k) {
                inbox.take(&p, Some(k), |t, _| got.push(t.tick));
            }
        }
        assert_eq!(got, [0, 1, 3, 4, 5, 6, 7]);
    }

    /// Regression: a reply for a future tick was remembered as taken, so the honest reply of
    /// that tick, when its state came, was dropped as a duplicate (and the plant missed it).
    #[test]
    fn regression_a_reply_for_a_future_tick_neither_passes_nor_shadows_the_honest_one() {
        let mut inbox = Inbox::default();
        let mut far = Outbox::default();
        let mut got = Vec::new();
        inbox.take(far.push(&reply(15), 0), Some(10), |t, _| got.push(t.tick));
        inbox.take(far.push(&reply(0), 0), None, |t, _| got.push(t.tick));
        assert!(got.is_empty(), "{got:?}");
        // 15, then 0 and its copy of 15 (before any state was sent).
        assert_eq!(inbox.future, 3);
        let mut honest = Outbox::default();
        for k in 11..=16u64 {
            inbox.take(honest.push(&reply(k), 0), Some(k), |t, _| got.push(t.tick));
        }
        assert_eq!(got, [11, 12, 13, 14, 15, 16]);
    }

    #[test]
    fn payload_sizes() {
        assert!(!valid_len(0));
        assert!(valid_len(ENTRY) && valid_len(COPIES * ENTRY));
        assert!(!valid_len(ENTRY + 1) && !valid_len((COPIES + 1) * ENTRY));
    }
}
