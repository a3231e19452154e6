//! Replies across the link, each datagram carrying the [`COPIES`] − 1 replies before it too, so
//! an isolated lost datagram costs the plant a late reply, never the record: the plant's host
//! still learns every state the controller answered, and the run replays byte for byte. (Without
//! it, a reply lost on the wire left a state the far controller had taken into its history
//! recorded as unanswered, and the replay's controller, given only answered states, differed.)
//!
//! A burst of more than [`COPIES`] lost datagrams loses replies the copies cannot bring back. The
//! far side numbers its replies (a sequence number in each entry) and keeps the last [`RING`] of
//! them; the near side sees the hole in the numbers ([`Inbox::take`] reports a [`Gap`]), asks for
//! it over the control connection ([`Recalls`], a RECALL frame) and publishes what comes back
//! (RECALLED) as it would a late reply. What cannot come back (out of the ring, the link gone)
//! is reported as a range of ticks whose replies are unknown.
//!
//! Wire: the payload of a [`Kind::Torque`](crate::frame::Kind) datagram is 1..=[`COPIES`]
//! entries, newest first, each a `TorqueMsg`, the far side's residence (u64, ns: state in to
//! reply out, on the far host's clock) and the reply's sequence number (u64, from 0). RECALL is
//! the first sequence number wanted and how many (two u64, 1..=[`RING`]); RECALLED is the same
//! two, then the entries of those still in the ring, oldest first.

use crate::bytes::{self, bytes_of};
use deltaloop_transport::wire::TorqueMsg;

/// Replies per datagram: the newest and the two before it.
pub const COPIES: usize = 3;
/// Bytes of one entry: a `TorqueMsg`, its residence and its sequence number.
pub const ENTRY: usize = size_of::<TorqueMsg>() + 16;
/// Replies the far side keeps for a recall (1.2 s at 3.3 kHz; 600 KiB, allocated at the start).
pub const RING: usize = 4096;
/// Bytes of a RECALL payload, and of the head of a RECALLED one: first, count.
pub const RECALL: usize = 16;

/// Whether `n` payload bytes are a whole number of entries, 1..=[`COPIES`].
pub fn valid_len(n: usize) -> bool {
    n.is_multiple_of(ENTRY) && (1..=COPIES).contains(&(n / ENTRY))
}

/// The far side's last replies, the payload that carries them, and the ring of the last
/// [`RING`] for recalls (all pre-allocated).
pub struct Outbox {
    buf: [u8; COPIES * ENTRY],
    len: usize,
    /// The next reply's sequence number.
    next_seq: u64,
    /// Entry of reply `seq` at `(seq % RING) * ENTRY`; valid for the last [`RING`] only.
    ring: Box<[u8]>,
    /// Recalls waiting for room on the control connection: (first, count).
    wanted: [(u64, u64); WANTED],
    n_wanted: usize,
    /// Recalls refused: malformed, of no reply, or beyond [`WANTED`] waiting.
    pub refused_recalls: u64,
}

/// Recalls the far side holds at once (the near side asks once per hole).
const WANTED: usize = 16;

impl Default for Outbox {
    fn default() -> Self {
        Self {
            buf: [0; COPIES * ENTRY],
            len: 0,
            next_seq: 0,
            ring: vec![0; RING * ENTRY].into_boxed_slice(),
            wanted: [(0, 0); WANTED],
            n_wanted: 0,
            refused_recalls: 0,
        }
    }
}

impl Outbox {
    /// Puts reply `t` (with its `residence_ns`) in front of the last ones, numbered; the payload
    /// to send.
    pub fn push(&mut self, t: &TorqueMsg, residence_ns: u64) -> &[u8] {
        self.buf.copy_within(0..(COPIES - 1) * ENTRY, ENTRY);
        let seq = self.next_seq;
        self.next_seq += 1;
        let e = &mut self.buf[..ENTRY];
        e[..ENTRY - 16].copy_from_slice(bytes_of(t));
        e[ENTRY - 16..ENTRY - 8].copy_from_slice(&residence_ns.to_ne_bytes());
        e[ENTRY - 8..].copy_from_slice(&seq.to_ne_bytes());
        let at = (seq % RING as u64) as usize * ENTRY;
        self.ring[at..at + ENTRY].copy_from_slice(&self.buf[..ENTRY]);
        self.len = (self.len + ENTRY).min(COPIES * ENTRY);
        self.payload()
    }

    /// The payload of the last push (empty before any).
    pub fn payload(&self) -> &[u8] {
        &self.buf[..self.len]
    }

    /// The newest reply's tick.
    pub fn newest_tick(&self) -> Option<u64> {
        entry(self.payload(), 0).map(|e| e.msg.tick)
    }

    /// A RECALL payload from the near side, held until [`Outbox::answer`] has room; refused
    /// (and counted) if malformed, empty, larger than the ring, or too many wait.
    pub fn recall(&mut self, p: &[u8]) {
        let ok = p.len() == RECALL && self.n_wanted < WANTED;
        let (first, count) = (word(p, 0), word(p, 1));
        if !ok || !(1..=RING as u64).contains(&count) || first.checked_add(count).is_none() {
            self.refused_recalls += 1;
            return;
        }
        self.wanted[self.n_wanted] = (first, count);
        self.n_wanted += 1;
    }

    /// The oldest recall held, answered through `send` (the RECALLED payload's parts: its head
    /// and the entries still in the ring, at most two slices of it); the rest wait for the next
    /// turn, so one turn copies at most one ring's worth.
    pub fn answer(
        &mut self,
        send: impl FnOnce(&[&[u8]]) -> anyhow::Result<()>,
    ) -> anyhow::Result<()> {
        if self.n_wanted == 0 {
            return Ok(());
        }
        let (first, count) = self.wanted[0];
        self.wanted.copy_within(1..self.n_wanted, 0);
        self.n_wanted -= 1;
        let mut head = [0u8; RECALL];
        head[..8].copy_from_slice(&first.to_ne_bytes());
        head[8..].copy_from_slice(&count.to_ne_bytes());
        // The ring holds [next − RING, next): the part of the recall in it.
        let lo = first.max(self.next_seq.saturating_sub(RING as u64));
        let hi = (first + count).min(self.next_seq);
        if lo >= hi {
            return send(&[&head]);
        }
        let (a, b) = ((lo % RING as u64) as usize, (hi % RING as u64) as usize);
        if a < b || b == 0 {
            let end = if b == 0 { RING } else { b };
            send(&[&head, &self.ring[a * ENTRY..end * ENTRY]])
        } else {
            send(&[&head, &self.ring[a * ENTRY..], &self.ring[..b * ENTRY]])
        }
    }
}

/// The `i`th u64 of `p` (0 if short).
fn word(p: &[u8], i: usize) -> u64 {
    p.get(i * 8..(i + 1) * 8)
        .and_then(bytes::read::<u64>)
        .unwrap_or(0)
}

/// One reply as the link carries it.
#[derive(Clone, Copy, Debug)]
pub struct Entry {
    pub msg: TorqueMsg,
    /// Its time on the far host, ns.
    pub residence_ns: u64,
    /// Its number among the far side's replies.
    pub seq: u64,
}

/// Entry `i` of a payload (0: the newest).
pub fn entry(p: &[u8], i: usize) -> Option<Entry> {
    let e = p.get(i * ENTRY..(i + 1) * ENTRY)?;
    Some(Entry {
        msg: bytes::read::<TorqueMsg>(&e[..ENTRY - 16])?,
        residence_ns: bytes::read::<u64>(&e[ENTRY - 16..ENTRY - 8])?,
        seq: bytes::read::<u64>(&e[ENTRY - 8..])?,
    })
}

/// Replies lost beyond the copies: sequence numbers `first..first + count`, for states after
/// tick `after` (None: before any reply) and before tick `before`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Gap {
    pub first: u64,
    pub count: u64,
    pub after: Option<u64>,
    pub before: u64,
}

impl Gap {
    /// The ticks whose replies it may hold, first..=last (None: none can).
    pub fn ticks(&self) -> Option<(u64, u64)> {
        ticks_between(self.after, self.before)
    }
}

/// The ticks strictly between two answered ones (None: none).
fn ticks_between(after: Option<u64>, before: u64) -> Option<(u64, u64)> {
    let first = after.map_or(0, |a| a + 1);
    (before > first).then(|| (first, before - 1))
}

/// Ticks the near side remembers having republished.
const SEEN: usize = 256;

/// The near side's record of the replies it republished, to take each once.
pub struct Inbox {
    /// tick + 1 at slot tick % SEEN (0: empty).
    seen: [u64; SEEN],
    /// The newest reply seen: its sequence number and tick.
    newest: Option<(u64, u64)>,
    /// Replies taken from an older copy (their own datagram was lost or overtaken).
    pub recovered: u64,
    /// Replies for a state not yet sent, left out (protocol §8: a future tick is ignored).
    pub future: u64,
    /// Replies lost beyond the copies (the holes in the sequence numbers).
    pub lost: u64,
}

impl Default for Inbox {
    fn default() -> Self {
        Self {
            seen: [0; SEEN],
            newest: None,
            recovered: 0,
            future: 0,
            lost: 0,
        }
    }
}

impl Inbox {
    /// The replies of payload `p` not taken before, oldest first, each once; `f` gets each with
    /// its residence. A reply for a tick past `newest_sent` (the newest state sent, None before
    /// the first) answers nothing and is left out before it is remembered, so it can never pass
    /// for, or shadow, the honest reply of that tick when it comes. Returns the replies lost
    /// before this payload's oldest, if its numbers skip some.
    pub fn take(
        &mut self,
        p: &[u8],
        newest_sent: Option<u64>,
        mut f: impl FnMut(TorqueMsg, u64),
    ) -> Option<Gap> {
        let n = p.len() / ENTRY;
        let (oldest, newest) = (entry(p, n.checked_sub(1)?)?, entry(p, 0)?);
        let expected = self.newest.map_or(0, |(s, _)| s + 1);
        let gap = (oldest.seq > expected).then(|| Gap {
            first: expected,
            count: oldest.seq - expected,
            after: self.newest.map(|(_, t)| t),
            before: oldest.msg.tick,
        });
        if let Some(g) = gap {
            self.lost += g.count;
        }
        if self.newest.is_none_or(|(s, _)| newest.seq > s) {
            self.newest = Some((newest.seq, newest.msg.tick));
        }
        for i in (0..n).rev() {
            if let Some(e) = entry(p, i)
                && self.take_one(e, newest_sent, &mut f)
                && i > 0
            {
                self.recovered += 1;
            }
        }
        gap
    }

    /// Takes one reply unless taken before or for a future tick; whether it was taken.
    fn take_one(
        &mut self,
        e: Entry,
        newest_sent: Option<u64>,
        f: &mut impl FnMut(TorqueMsg, u64),
    ) -> bool {
        let t = e.msg;
        if newest_sent.is_none_or(|k| t.tick > k) {
            self.future += 1;
            return false;
        }
        let slot = &mut self.seen[(t.tick % SEEN as u64) as usize];
        if *slot == t.tick.wrapping_add(1) {
            return false;
        }
        *slot = t.tick.wrapping_add(1);
        f(t, e.residence_ns);
        true
    }
}

/// Holes the near side follows at once; the ticks of one more are reported unknown at once.
const HOLES: usize = 32;

/// How long a recall may take before the ticks of its hole are reported unknown, ns: well
/// inside the supervisor's window (it files a reply up to 2.5 s late).
pub const RECALL_WAIT_NS: u64 = 500_000_000;

/// The near side's holes in the far side's replies: asked for, recovered, or reported as ticks
/// whose replies are unknown. Fixed size.
#[derive(Default)]
pub struct Recalls {
    /// Each hole and when it was asked for (None: not yet).
    holes: [Option<(Gap, Option<u64>)>; HOLES],
    /// Ticks of holes there was no room for, merged, not yet reported.
    overflow: Option<(u64, u64)>,
    /// Replies brought back by a recall.
    pub recalled: u64,
    /// Replies a recall could not bring back.
    pub unknown: u64,
    /// RECALLED payloads refused: malformed, or for no hole asked.
    pub refused: u64,
}

impl Recalls {
    /// Follows hole `g` (a recall goes out with the next [`Recalls::ask`]).
    pub fn hole(&mut self, g: Gap) {
        match self.holes.iter_mut().find(|h| h.is_none()) {
            Some(h) => *h = Some((g, None)),
            None => {
                self.unknown += g.count;
                if let Some((a, b)) = g.ticks() {
                    self.overflow =
                        Some(self.overflow.map_or((a, b), |(x, y)| (x.min(a), y.max(b))));
                }
            }
        }
    }

    /// Whether a hole is followed or a report is due.
    pub fn busy(&self) -> bool {
        self.overflow.is_some() || self.holes.iter().any(Option::is_some)
    }

    /// The RECALL payload of each hole not yet asked for, through `send`.
    pub fn ask(
        &mut self,
        now: u64,
        mut send: impl FnMut(&[u8]) -> anyhow::Result<()>,
    ) -> anyhow::Result<()> {
        for (g, asked) in self.holes.iter_mut().flatten() {
            if asked.is_none() {
                // The older part of a hole larger than the ring is gone already; the far side
                // answers what it still has.
                let count = g.count.min(RING as u64);
                let first = g.first + (g.count - count);
                let mut p = [0u8; RECALL];
                p[..8].copy_from_slice(&first.to_ne_bytes());
                p[8..].copy_from_slice(&count.to_ne_bytes());
                send(&p)?;
                *asked = Some(now);
            }
        }
        Ok(())
    }

    /// Reports (`unknown`: first and last tick) the holes asked for more than
    /// [`RECALL_WAIT_NS`] ago, every hole if `all` (the link is gone), and those there was no
    /// room for.
    pub fn give_up(&mut self, now: u64, all: bool, mut unknown: impl FnMut(u64, u64)) {
        if let Some((a, b)) = self.overflow.take() {
            unknown(a, b);
        }
        for h in &mut self.holes {
            let due =
                h.is_some_and(|(_, asked)| all || asked.is_some_and(|t| now > t + RECALL_WAIT_NS));
            if let Some((g, _)) = h.take_if(|_| due) {
                self.unknown += g.count;
                if let Some((a, b)) = g.ticks() {
                    unknown(a, b);
                }
            }
        }
    }

    /// A RECALLED payload: its replies through `inbox` to `publish` (each once, oldest first),
    /// and the ticks of those it lacks to `unknown`. A payload for no hole asked, or malformed,
    /// is refused and counted; never trusted beyond the hole it answers.
    pub fn answered(
        &mut self,
        p: &[u8],
        (inbox, newest_sent): (&mut Inbox, Option<u64>),
        mut publish: impl FnMut(TorqueMsg, u64),
        mut unknown: impl FnMut(u64, u64),
    ) {
        let (first, count) = (word(p, 0), word(p, 1));
        let body = p.get(RECALL..).unwrap_or_default();
        let hole = self.holes.iter_mut().find(|h| {
            h.is_some_and(|(g, asked)| {
                asked.is_some()
                    && first.checked_add(count) == Some(g.first + g.count)
                    && count <= g.count
            })
        });
        let (Some(hole), true) = (hole, p.len() >= RECALL && body.len().is_multiple_of(ENTRY))
        else {
            self.refused += 1;
            return;
        };
        let Some((g, _)) = hole.take() else {
            return;
        };
        let end = g.first + g.count;
        let (mut expect, mut prev) = (g.first, g.after);
        for i in 0..body.len() / ENTRY {
            let Some(e) = entry(body, i).filter(|e| (expect.max(first)..end).contains(&e.seq))
            else {
                // Out of order or out of the hole: the rest is not believed.
                self.refused += 1;
                break;
            };
            if e.seq > expect {
                self.unknown += e.seq - expect;
                if let Some((a, b)) = ticks_between(prev, e.msg.tick) {
                    unknown(a, b);
                }
            }
            inbox.take_one(e, newest_sent, &mut publish);
            self.recalled += 1;
            (expect, prev) = (e.seq + 1, Some(e.msg.tick));
        }
        if expect < end {
            self.unknown += end - expect;
            if let Some((a, b)) = ticks_between(prev, g.before) {
                unknown(a, b);
            }
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

    /// The far side's RECALLED payload for a RECALL payload (its parts joined).
    fn answer(far: &mut Outbox, recall: &[u8]) -> Vec<u8> {
        far.recall(recall);
        let mut out = Vec::new();
        far.answer(|parts| {
            out = parts.concat();
            Ok(())
        })
        .unwrap();
        out
    }

    /// Five datagrams lost in a row: the hole is seen from the numbers, between the right ticks,
    /// recalled from the far side's ring, and every reply is taken once; a hole that fell out of
    /// the ring is reported as the ticks whose replies are unknown.
    #[test]
    fn a_burst_beyond_the_copies_is_seen_and_recalled_from_the_ring() {
        let (mut far, mut inbox, mut recalls) =
            (Outbox::default(), Inbox::default(), Recalls::default());
        let mut got = Vec::new();
        let mut asked = Vec::new();
        for k in 0..12u64 {
            let p = far.push(&reply(k), 0).to_vec();
            // Datagrams 3..=7 lost: 8 carries 7 and 6, so 3..=5 are lost beyond the copies.
            if !(3..=7).contains(&k)
                && let Some(g) = inbox.take(&p, Some(k), |t, _| got.push(t.tick))
            {
                assert_eq!(
                    g,
                    Gap {
                        first: 3,
                        count: 3,
                        after: Some(2),
                        before: 6
                    }
                );
                assert_eq!(g.ticks(), Some((3, 5)));
                recalls.hole(g);
            }
        }
        assert_eq!(inbox.lost, 3);
        recalls
            .ask(0, |p| {
                asked.push(p.to_vec());
                Ok(())
            })
            .unwrap();
        assert_eq!(asked.len(), 1);
        let back = answer(&mut far, &asked[0]);
        assert_eq!(back.len(), RECALL + 3 * ENTRY);
        let mut unknown = Vec::new();
        recalls.answered(
            &back,
            (&mut inbox, Some(11)),
            |t, _| got.push(t.tick),
            |a, b| unknown.push((a, b)),
        );
        got.sort_unstable();
        assert_eq!(got, (0..12).collect::<Vec<_>>());
        assert!(unknown.is_empty(), "{unknown:?}");
        assert_eq!(
            (recalls.recalled, recalls.unknown, recalls.refused),
            (3, 0, 0)
        );
        // The same answer again answers no hole: refused, nothing taken.
        recalls.answered(
            &back,
            (&mut inbox, Some(11)),
            |t, _| got.push(t.tick),
            |a, b| unknown.push((a, b)),
        );
        assert_eq!((got.len(), recalls.refused), (12, 1));

        // A hole the ring has forgotten: its ticks are unknown.
        for k in 12..12 + RING as u64 + 10 {
            far.push(&reply(k), 0);
        }
        recalls.hole(Gap {
            first: 0,
            count: 2,
            after: Some(40),
            before: 44,
        });
        asked.clear();
        recalls
            .ask(0, |p| {
                asked.push(p.to_vec());
                Ok(())
            })
            .unwrap();
        let back = answer(&mut far, &asked[0]);
        assert_eq!(back.len(), RECALL);
        recalls.answered(
            &back,
            (&mut inbox, Some(u64::MAX - 1)),
            |_, _| panic!("nothing to take"),
            |a, b| unknown.push((a, b)),
        );
        assert_eq!(unknown, [(41, 43)]);
        assert!(!recalls.busy());
    }

    /// A recall that never comes back (the link went down) is reported when it is overdue, or
    /// at once when the link is gone; what a peer sends wrong is refused and counted.
    #[test]
    fn an_unanswered_recall_is_reported_and_bad_recalls_are_refused() {
        let mut recalls = Recalls::default();
        recalls.hole(Gap {
            first: 5,
            count: 4,
            after: Some(9),
            before: 20,
        });
        recalls.ask(1_000, |_| Ok(())).unwrap();
        let mut unknown = Vec::new();
        recalls.give_up(1_000 + RECALL_WAIT_NS, false, |a, b| unknown.push((a, b)));
        assert!(unknown.is_empty() && recalls.busy());
        recalls.give_up(1_001 + RECALL_WAIT_NS, false, |a, b| unknown.push((a, b)));
        assert_eq!(unknown, [(10, 19)]);
        recalls.hole(Gap {
            first: 9,
            count: 1,
            after: None,
            before: 3,
        });
        recalls.give_up(0, true, |a, b| unknown.push((a, b)));
        assert_eq!(unknown, [(10, 19), (0, 2)]);
        // Every slot taken: one more hole is reported as it is.
        for i in 0..HOLES as u64 {
            recalls.hole(Gap {
                first: 100 + i,
                count: 1,
                after: Some(i),
                before: i + 2,
            });
        }
        recalls.hole(Gap {
            first: 900,
            count: 1,
            after: Some(50),
            before: 60,
        });
        unknown.clear();
        recalls.give_up(0, false, |a, b| unknown.push((a, b)));
        assert_eq!(unknown, [(51, 59)]);
        // Junk answers: refused, never a panic.
        let mut inbox = Inbox::default();
        for junk in [
            &[][..],
            &[1u8; 7],
            &[0u8; RECALL + 5],
            &[0xff; RECALL + ENTRY],
        ] {
            recalls.answered(junk, (&mut inbox, Some(10)), |_, _| panic!(), |_, _| {});
        }
        assert_eq!(recalls.refused, 4);
        let mut far = Outbox::default();
        let recall = |first: u64, count: u64| [first.to_ne_bytes(), count.to_ne_bytes()].concat();
        for bad in [
            recall(0, 0),
            recall(0, RING as u64 + 1),
            recall(u64::MAX, 2),
            vec![1, 2, 3],
        ] {
            far.recall(&bad);
        }
        assert_eq!(far.refused_recalls, 4);
        far.answer(|_| panic!("nothing held")).unwrap();
    }

    #[test]
    fn payload_sizes() {
        assert!(!valid_len(0));
        assert!(valid_len(ENTRY) && valid_len(COPIES * ENTRY));
        assert!(!valid_len(ENTRY + 1) && !valid_len((COPIES + 1) * ENTRY));
    }
}
