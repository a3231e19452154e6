//! The direct path: plant and controller exchange state and torque socket to socket, sealed as
//! on the relay path, with no process between them (two wake-ups per round trip, as a UDP
//! ping-pong has). The bridge on each host keeps the TCP control connection (set-up, START and
//! STOP, the reference, logs, telemetry and a copy of each message for the record) and, at START,
//! hands its UDP socket and the sealing state to the loop process beside it
//! (`deltaloop_transport::handoff`): the counters go on where the bridge stopped, so no nonce
//! repeats under a key, and the far side cannot tell which process answers.
//!
//! The datagrams are those of the relay ([`crate::frame`], [`crate::replies`]), so each host
//! decides alone: a loop process that speaks only iceoryx2 is relayed by its bridge, and the
//! other host still goes direct.
//!
//! - [`PlantEnd`]: the plant's socket. States out (lockstep: sent again every
//!   [`RESEND_NS`] until answered), replies in, each with the residence
//!   on the controller's host, restamped on arrival here as the relay did.
//! - [`ControllerEnd`]: the controller's socket. States in (a repeat of the state last answered
//!   gets the last reply again), replies out with the two before them and their residence.
//!
//! Neither allocates after set-up; the only syscalls are the socket's and the clock.

use crate::bytes::{self, bytes_of};
use crate::emulation::Emulation;
use crate::frame::Kind;
use crate::offset::Offset;
use crate::replies::{Inbox, Outbox};
use crate::seal::{End, KEY_LEN, Opener, Sealer, Session};
pub use crate::udp::ProcessCounts;
use crate::udp::{self as link, Udp};
use anyhow::{Context, Result, bail};
use deltaloop_transport::handoff::{self, Tag};
use deltaloop_transport::rt;
use deltaloop_transport::wire::{self, StateMsg, TorqueMsg};
use std::net::UdpSocket;
use std::os::fd::AsRawFd;

/// Lockstep: how long to wait for a reply before sending its state again, ns.
pub const RESEND_NS: u64 = 5_000_000;

/// What a bridge hands on with its socket: the session, the sealing state, the emulation.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Offer {
    pub session: u64,
    seal_key: [u8; KEY_LEN],
    open_key: [u8; KEY_LEN],
    /// The counter of the next datagram sealed.
    next: u64,
    /// The highest counter opened (None: none yet).
    top: Option<u64>,
    pub emu: Emulation,
}

/// Bytes of an encoded [`Offer`].
pub const OFFER_LEN: usize = 8 + 2 * KEY_LEN + 8 + 8 + 8 + 8 + 4 + 8;

impl Offer {
    /// The offer of `udp`, a socket of `session` at end `me`.
    pub fn of(udp: &Udp, session: &Session, me: End) -> Self {
        let (seal_key, open_key) = session.udp_keys(me);
        let (next, top) = udp.counters();
        Self {
            session: session.id,
            seal_key,
            open_key,
            next,
            top,
            emu: udp.emulation(),
        }
    }

    pub fn encode(&self) -> [u8; OFFER_LEN] {
        let mut b = [0u8; OFFER_LEN];
        let mut at = 0;
        let mut put = |v: &[u8]| {
            b[at..at + v.len()].copy_from_slice(v);
            at += v.len();
        };
        put(&self.session.to_le_bytes());
        put(&self.seal_key);
        put(&self.open_key);
        put(&self.next.to_le_bytes());
        put(&self.top.map_or(u64::MAX, |t| t).to_le_bytes());
        put(&self.emu.delay_ns.to_le_bytes());
        put(&self.emu.jitter_ns.to_le_bytes());
        put(&self.emu.loss_ppm.to_le_bytes());
        put(&self.emu.seed.to_le_bytes());
        b
    }

    pub fn decode(b: &[u8]) -> Option<Self> {
        if b.len() != OFFER_LEN {
            return None;
        }
        let u64_at = |i: usize| u64::from_le_bytes(b[i..i + 8].try_into().unwrap_or([0; 8]));
        let key_at =
            |i: usize| -> [u8; KEY_LEN] { b[i..i + KEY_LEN].try_into().unwrap_or([0; 32]) };
        let k = 8 + 2 * KEY_LEN;
        let top = u64_at(k + 8);
        Some(Self {
            session: u64_at(0),
            seal_key: key_at(8),
            open_key: key_at(8 + KEY_LEN),
            next: u64_at(k),
            top: (top != u64::MAX).then_some(top),
            emu: Emulation {
                delay_ns: u64_at(k + 16),
                jitter_ns: u64_at(k + 24),
                loss_ppm: u32::from_le_bytes(b[k + 32..k + 36].try_into().unwrap_or([0; 4])),
                seed: u64_at(k + 36),
            },
        })
    }
}

/// The bridge's side of the hand-off at START: if the loop process said HELLO (its version),
/// the socket of `udp` and its sealing state go to it and `Ok(true)`; else RELAY (if it said
/// anything) and `Ok(false)`. `relay`: the run asks for the relay (`[link] path = "relay"`).
pub fn offer(
    end: &handoff::End,
    udp: &mut Udp,
    session: &Session,
    me: End,
    relay: bool,
) -> Result<bool> {
    let mut buf = [0u8; handoff::MAX_MSG];
    let mut hello = false;
    while let Some((tag, n, _)) = end.recv(&mut buf, 0)? {
        hello |= tag == Tag::Hello && n == 2 && buf[..2] == handoff::VERSION.to_le_bytes();
    }
    if !hello {
        return Ok(false);
    }
    if relay {
        end.send(Tag::Relay, &[], None)?;
        return Ok(false);
    }
    // Nothing held back stays behind with the bridge.
    while let Some(due) = udp.next_due() {
        let now = rt::now_ns();
        if due > now {
            std::thread::sleep(std::time::Duration::from_nanos(due - now));
        }
        udp.flush(rt::now_ns())?;
    }
    let o = Offer::of(udp, session, me);
    end.send(Tag::Offer, &o.encode(), Some(udp.sock.as_raw_fd()))
        .context("hand the link's socket to the loop process")?;
    Ok(true)
}

/// How long a loop process that said HELLO waits at START for its bridge's answer, ns.
pub const ANSWER_WAIT_NS: u64 = 2_000_000_000;

/// A loop process's side: HELLO at set-up (None: no hand-off was given to it).
pub fn hello() -> Result<Option<handoff::End>> {
    let Some(end) = handoff::End::inherited() else {
        return Ok(None);
    };
    end.send(Tag::Hello, &handoff::VERSION.to_le_bytes(), None)
        .context("say HELLO to the bridge")?;
    Ok(Some(end))
}

/// A loop process's side at START: the bridge's answer (within [`ANSWER_WAIT_NS`]): the link's
/// socket (Some) or the relay (None).
pub fn answer(end: &handoff::End) -> Result<Option<Udp>> {
    let mut buf = [0u8; handoff::MAX_MSG];
    let until = rt::now_ns() + ANSWER_WAIT_NS;
    loop {
        let left = until.saturating_sub(rt::now_ns());
        let Some((tag, n, fd)) = end.recv(&mut buf, left)? else {
            bail!(
                "the bridge gave no answer to this process's HELLO within {} s (the link's socket or the relay)",
                ANSWER_WAIT_NS / 1_000_000_000
            );
        };
        match (tag, fd) {
            (Tag::Relay, _) => return Ok(None),
            (Tag::Offer, Some(fd)) => {
                let Some(o) = Offer::decode(&buf[..n]) else {
                    bail!("the bridge's offer of the link is malformed ({n} bytes)");
                };
                let sock = UdpSocket::from(fd);
                let sealing = (
                    Sealer::resume(&o.seal_key, o.next),
                    Opener::resume(&o.open_key, o.top),
                );
                return Ok(Some(Udp::resumed(sock, o.session, sealing, o.emu)?));
            }
            _ => {}
        }
    }
}

/// Bytes of the counts in a COUNTS message, before the first refusal's reason.
const COUNTS_LEN: usize = 6 * 8;

/// A loop process's closing word to its bridge: what its socket refused (by reason, and the
/// first reason in words), what the emulation dropped and the ICMP-reported errors, for the
/// run's link report.
pub fn counts(end: &handoff::End, udp: &Udp) {
    let mut b = [0u8; handoff::MAX_MSG - 1];
    let words = udp
        .refused
        .counts
        .iter()
        .chain([&udp.emulated_lost, &udp.icmp_errors]);
    for (i, n) in words.enumerate() {
        b[i * 8..i * 8 + 8].copy_from_slice(&n.to_le_bytes());
    }
    let why = udp.last_refusal.as_deref().unwrap_or("").as_bytes();
    let n = why.len().min(b.len() - COUNTS_LEN);
    b[COUNTS_LEN..COUNTS_LEN + n].copy_from_slice(&why[..n]);
    let _ = end.send(Tag::Counts, &b[..COUNTS_LEN + n], None);
}

/// The bridge's reading of [`counts`], if the process said them.
pub fn read_counts(end: &handoff::End) -> Option<ProcessCounts> {
    let mut buf = [0u8; handoff::MAX_MSG];
    let mut got = None;
    while let Ok(Some((tag, n, _))) = end.recv(&mut buf, 0) {
        if tag == Tag::Counts && n >= COUNTS_LEN {
            let w =
                |i: usize| u64::from_le_bytes(buf[i * 8..i * 8 + 8].try_into().unwrap_or([0; 8]));
            let why = String::from_utf8_lossy(&buf[COUNTS_LEN..n]);
            got = Some(ProcessCounts {
                refused: [w(0), w(1), w(2), w(3)],
                emulated_lost: w(4),
                icmp_errors: w(5),
                first_refusal: (!why.is_empty()).then(|| wire::escape_peer_text(&why)),
            });
        }
    }
    got
}

/// The plant's socket on the direct path.
pub struct PlantEnd {
    pub udp: Udp,
    inbox: Inbox,
    /// The newest state sent (None before the first).
    newest_sent: Option<u64>,
    /// Lockstep: the state awaiting its reply and when to send it again.
    resend: Option<(StateMsg, Option<u64>)>,
    /// States sent again (lockstep).
    pub resent: u64,
}

impl PlantEnd {
    pub fn new(udp: Udp, lockstep: bool) -> Self {
        Self {
            udp,
            inbox: Inbox::default(),
            newest_sent: None,
            resend: lockstep.then_some((StateMsg::default(), None)),
            resent: 0,
        }
    }

    /// State `s` out (the final state goes over the bridge's control connection).
    pub fn send_state(&mut self, s: &StateMsg) -> Result<()> {
        let now = rt::now_ns();
        self.udp.send(Kind::State, &[bytes_of(s)], now)?;
        self.newest_sent = Some(s.tick);
        if let Some(r) = &mut self.resend {
            *r = (*s, Some(now + RESEND_NS));
        }
        Ok(())
    }

    /// The held datagrams and a due resend out, then the replies in: `f` gets each reply not
    /// taken before, oldest first, stamped on this host's clock (`t_publish_ns` = its arrival,
    /// `t_state_rx_ns` = that less its residence on the controller's host).
    pub fn poll(&mut self, mut f: impl FnMut(TorqueMsg)) -> Result<()> {
        let now = rt::now_ns();
        self.udp.flush(now)?;
        if let Some((s, Some(due))) = &mut self.resend
            && now >= *due
        {
            *due = now + RESEND_NS;
            let s = *s;
            self.udp.send(Kind::State, &[bytes_of(&s)], now)?;
            self.resent += 1;
        }
        let (inbox, newest, resend) = (&mut self.inbox, self.newest_sent, &mut self.resend);
        while let Some((kind, p, rx)) = self.udp.recv_stamped()? {
            if kind != Kind::Torque {
                continue;
            }
            inbox.take(p, newest, |mut t, residence| {
                // When the reply reached this host (the kernel's stamp), not when the plant
                // looked: a plant preempted after it came does not charge its own delay to the
                // controller as latency, or as a miss (as on one host, where the controller's
                // publish stamp counts).
                let at = rx.unwrap_or_else(rt::now_ns);
                t.t_publish_ns = at;
                t.t_state_rx_ns = at.saturating_sub(residence);
                t.t_poll_until_ns = 0;
                if let Some((s, due)) = resend
                    && s.tick == t.tick
                {
                    *due = None;
                }
                f(t);
            });
        }
        Ok(())
    }

    /// How long a wait may block before the next held datagram or resend is due, ns.
    pub fn timeout_ns(&self, now: u64) -> u64 {
        let resend = self
            .resend
            .and_then(|(_, d)| d)
            .map_or(u64::MAX, |d| d.saturating_sub(now));
        due_timeout(&self.udp, now).min(resend)
    }

    /// Replies taken from a later datagram, and lost beyond the copies.
    pub fn recovered_lost(&self) -> (u64, u64) {
        (self.inbox.recovered, self.inbox.lost)
    }
}

/// How long to block before the next emulated datagram is due (polling within
/// [`link::EMULATION_SPIN_NS`] of it), ns; unbounded when none is held.
fn due_timeout(udp: &Udp, now: u64) -> u64 {
    match udp.next_due().map(|d| d.saturating_sub(now)) {
        Some(left) if left <= link::EMULATION_SPIN_NS => 0,
        Some(left) => left - link::EMULATION_SPIN_NS,
        None => u64::MAX,
    }
}

/// The controller's socket on the direct path.
pub struct ControllerEnd {
    pub udp: Udp,
    replies: Outbox,
    /// The states' stamps move onto this host's clock (the plant's is another host's).
    local_stamps: bool,
    offset: Offset,
}

impl ControllerEnd {
    pub fn new(udp: Udp, local_stamps: bool) -> Self {
        Self {
            udp,
            replies: Outbox::default(),
            local_stamps,
            offset: Offset::default(),
        }
    }

    /// The held datagrams out, then the states in: the newest (its stamps on this host's clock
    /// where the supervisor is here) and how many older ones came with it, None if none. A
    /// repeat of the state last answered (its reply was lost: lockstep sends it again) gets that
    /// reply again.
    pub fn poll(&mut self) -> Result<Option<(StateMsg, u64)>> {
        let now = rt::now_ns();
        self.udp.flush(now)?;
        let mut newest: Option<StateMsg> = None;
        let mut older = 0;
        while let Some((kind, p)) = self.udp.recv()? {
            if kind != Kind::State {
                continue;
            }
            let Some(s) = bytes::read::<StateMsg>(p) else {
                continue;
            };
            if self.replies.newest_tick() == Some(s.tick) {
                let payload = self.replies.payload();
                self.udp.send(Kind::Torque, &[payload], now)?;
                continue;
            }
            match newest {
                Some(n) if n.tick >= s.tick => older += u64::from(n.tick > s.tick),
                Some(_) => {
                    older += 1;
                    newest = Some(s);
                }
                None => newest = Some(s),
            }
        }
        Ok(newest.map(|s| (self.stamped(s), older)))
    }

    /// A state's stamps on this host's clock, if the plant is across (as the relay's far side
    /// stamped them: the offset seen on the quickest recent states, the arrival as publication).
    fn stamped(&mut self, mut s: StateMsg) -> StateMsg {
        if !self.local_stamps || s.flags & wire::STATE_FINAL != 0 {
            return s;
        }
        self.offset.restamp(&mut s, rt::now_ns());
        s
    }

    /// Reply `t` out, with the two before it and its residence here (its state's take to its
    /// publication, both stamped by the controller).
    pub fn send_reply(&mut self, t: &TorqueMsg) -> Result<()> {
        let residence = t.t_publish_ns.saturating_sub(t.t_state_rx_ns);
        let payload = self.replies.push(t, residence);
        self.udp.send(Kind::Torque, &[payload], rt::now_ns())
    }

    /// How long a wait may block before the next held datagram is due, ns.
    pub fn timeout_ns(&self, now: u64) -> u64 {
        due_timeout(&self.udp, now)
    }

    /// Sleeps until `t_ns` (the controller's schedule), sending each held datagram when it is
    /// due on the way (regression: with an emulated delay the reply waited in the queue while
    /// the controller slept to the next deadline, and every reply came late).
    pub fn sleep_until(&mut self, t_ns: u64) -> Result<()> {
        while let Some(due) = self.udp.next_due().filter(|d| *d < t_ns) {
            hold_until(due);
            self.udp.flush(rt::now_ns())?;
        }
        rt::sleep_until_ns(t_ns);
        Ok(())
    }
}

/// Waits until `t_ns`: sleeps to [`link::EMULATION_SPIN_NS`] before it, then polls the clock (a
/// timed wake-up on a VM comes tens of µs late, which an emulated delay would gain).
fn hold_until(t_ns: u64) {
    rt::sleep_until_ns(t_ns.saturating_sub(link::EMULATION_SPIN_NS));
    while rt::now_ns() < t_ns {
        std::hint::spin_loop();
    }
}

/// A pollfd for the socket of `udp`.
pub fn readable(udp: &Udp) -> libc::pollfd {
    link::readable(&udp.sock)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_offer_survives_its_encoding() {
        let s = Session::generate().unwrap();
        let (a, _) = (
            UdpSocket::bind("127.0.0.1:0").unwrap(),
            UdpSocket::bind("127.0.0.1:0").unwrap(),
        );
        let emu = Emulation {
            delay_ns: 7,
            jitter_ns: 9,
            loss_ppm: 11,
            seed: 13,
        };
        let udp = Udp::sealed(a, &s, End::Near, emu).unwrap();
        let o = Offer::of(&udp, &s, End::Near);
        assert_eq!(Offer::decode(&o.encode()), Some(o));
        assert_eq!(o.emu, emu);
        assert_eq!(Offer::decode(&o.encode()[1..]), None);
    }

    /// The hand-off at START: the loop process gets the bridge's socket through the pair, and
    /// its datagrams go on from the bridge's counters (none repeats a nonce: the far side opens
    /// every one, refusing none as replayed), while a datagram the bridge had taken is refused
    /// when it comes again. A process that never said HELLO is not offered the socket.
    #[test]
    fn the_socket_handed_on_goes_on_from_the_bridges_counters() {
        let s = Session::generate().unwrap();
        let (a, b) = (
            UdpSocket::bind("127.0.0.1:0").unwrap(),
            UdpSocket::bind("127.0.0.1:0").unwrap(),
        );
        a.connect(b.local_addr().unwrap()).unwrap();
        b.connect(a.local_addr().unwrap()).unwrap();
        let raw_far = b.try_clone().unwrap();
        let mut near = Udp::sealed(a, &s, End::Near, Emulation::default()).unwrap();
        let mut far = Udp::sealed(b, &s, End::Far, Emulation::default()).unwrap();
        let st = |tick| StateMsg {
            tick,
            ..StateMsg::default()
        };
        let heard = |far: &mut Udp| {
            std::thread::sleep(std::time::Duration::from_millis(10));
            let mut got = Vec::new();
            while let Some((_, p)) = far.recv().unwrap() {
                got.push(bytes::read::<StateMsg>(p).unwrap().tick);
            }
            got
        };
        // The far side's first datagram, taken by the bridge, and a copy of its bytes.
        far.send(Kind::Punch, &[], 0).unwrap();
        let mut punch = [0u8; 128];
        std::thread::sleep(std::time::Duration::from_millis(10));
        let n = near.sock.peek(&mut punch).unwrap();
        assert!(near.recv().unwrap().is_some());
        for k in 0..3 {
            near.send(Kind::State, &[bytes_of(&st(k))], 0).unwrap();
        }
        assert_eq!(heard(&mut far), [0, 1, 2]);

        let (bridge, process) = handoff::pair().unwrap();
        assert!(
            !offer(&bridge, &mut near, &s, End::Near, false).unwrap(),
            "no HELLO"
        );
        process
            .send(Tag::Hello, &handoff::VERSION.to_le_bytes(), None)
            .unwrap();
        assert!(offer(&bridge, &mut near, &s, End::Near, false).unwrap());
        let mut taken = answer(&process).unwrap().expect("the socket");
        for k in 3..6 {
            taken.send(Kind::State, &[bytes_of(&st(k))], 0).unwrap();
        }
        assert_eq!(heard(&mut far), [3, 4, 5]);
        assert_eq!(far.refused.total(), 0, "{:?}", far.refused);
        raw_far.send(&punch[..n]).unwrap();
        std::thread::sleep(std::time::Duration::from_millis(10));
        assert!(taken.recv().unwrap().is_none());
        assert_eq!(
            taken.refused.counts[crate::seal::Refusal::Replayed as usize],
            1
        );
        // The run that asks for the relay answers RELAY.
        let (bridge, process) = handoff::pair().unwrap();
        process
            .send(Tag::Hello, &handoff::VERSION.to_le_bytes(), None)
            .unwrap();
        assert!(!offer(&bridge, &mut near, &s, End::Near, true).unwrap());
        assert!(answer(&process).unwrap().is_none());
    }
}
