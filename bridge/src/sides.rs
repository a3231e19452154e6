//! The two halves of the loop across the link, whichever side of it the supervisor is on.
//!
//! - [`PlantHost`]: the bridge on the plant's host holds the controller's loop ports: the plant's
//!   states go out as datagrams (the final one over TCP), the replies come back and are
//!   republished stamped on this host's clock (docs/protocol.md §14). The near side with
//!   `--controller-remote`, the far side with `--plant-remote`.
//! - [`ControllerHost`]: the bridge on the controller's host holds the plant's loop ports: the
//!   states from the link are published here, the controller's replies go back with their
//!   residence here. The far side with `--controller-remote`, the near side with `--plant-remote`.
//!
//! Neither allocates, locks or makes a syscall beyond the sockets, iceoryx2 and the clock.

use crate::bytes::{self, bytes_of};
use crate::frame::Kind;
use crate::link::{self, Tcp, Udp};
use crate::replies::{Inbox, Outbox, Recalls};
use anyhow::Result;
use deltaloop_transport::ipc::{self, IpcContext};
use deltaloop_transport::rt;
use deltaloop_transport::wire::{self, ControlKind, ControlMsg, Sender, StateMsg, TorqueMsg};

pub use deltaloop_link::direct::RESEND_NS;

/// The plant's host: states out, replies in (see the module).
pub struct PlantHost {
    /// The last state sent: its tick and the plant's `t_poll_until_ns`.
    last_state: (u64, u64),
    /// When the final state went to the other side.
    pub final_sent_ns: Option<u64>,
    /// How long to poll for the reply after sending a state, ns.
    spin_ns: u64,
    /// Poll (do not block) until then: a reply is due.
    poll_until: u64,
    /// Lockstep only: the state awaiting its reply, sent again every [`RESEND_NS`] until the
    /// reply comes, so a lost datagram costs time, never the run (the other side answers a
    /// repeated state with its cached reply). In realtime a lost state or reply is a miss, as it
    /// should be.
    resend: Option<Resend>,
    /// States sent again (lockstep).
    pub resent: u64,
    /// States of a backlog not sent: a newer one went instead (realtime).
    pub stale: u64,
    /// Every state also goes over TCP, for the record on the other host (`--plant-remote`: the
    /// supervisor there records every state, including one lost on the link).
    record: bool,
    /// The replies republished, each once (a datagram carries the two before it too).
    pub inbox: Inbox,
    /// Replies lost beyond the copies are recalled over TCP (`--controller-remote`: the record
    /// is on this host and must learn every reply the far controller sent).
    recall: bool,
    /// The holes being recalled.
    pub recalls: Recalls,
    /// The plant took the link's socket (the direct path): no datagram goes through here; the
    /// final state, and with `record` a copy of every state, still go over TCP.
    pub direct: bool,
    /// The newest state the plant published here (its tick): the loop's clock, as the
    /// supervisor here sees it.
    pub newest_state: Option<u64>,
}

/// What a [`PlantHost`] counted on the link, for its closing line.
#[derive(Clone, Copy, Debug, Default)]
pub struct PlantHostCounts {
    /// States sent again (lockstep).
    pub resent: u64,
    /// States of a backlog not sent: a newer one went instead (realtime).
    pub stale: u64,
    /// Replies taken from a later datagram.
    pub recovered: u64,
    /// Replies for a state not yet sent, left out.
    pub future: u64,
    /// Replies lost beyond the copies (holes in the far side's numbers).
    pub lost: u64,
    /// Of those, brought back by a recall, and not.
    pub recalled: u64,
    pub unknown: u64,
    /// Recall answers refused (malformed, or for no hole asked).
    pub refused_recalls: u64,
}

struct Resend {
    state: StateMsg,
    /// When to send it again; None once its reply came.
    due_ns: Option<u64>,
}

impl PlantHost {
    pub fn new(spin_ns: u64, lockstep: bool) -> Self {
        Self {
            last_state: (u64::MAX, 0),
            final_sent_ns: None,
            spin_ns,
            poll_until: 0,
            resend: lockstep.then_some(Resend {
                state: StateMsg::default(),
                due_ns: None,
            }),
            resent: 0,
            stale: 0,
            record: false,
            inbox: Inbox::default(),
            recall: false,
            recalls: Recalls::default(),
            direct: false,
            newest_state: None,
        }
    }

    /// What was counted on the link.
    pub fn counts(&self) -> PlantHostCounts {
        PlantHostCounts {
            resent: self.resent,
            stale: self.stale,
            recovered: self.inbox.recovered,
            future: self.inbox.future,
            lost: self.inbox.lost,
            recalled: self.recalls.recalled,
            unknown: self.recalls.unknown,
            refused_recalls: self.recalls.refused,
        }
    }

    /// Replies lost beyond the copies are recalled (see the field).
    pub fn with_recall(self) -> Self {
        Self {
            recall: true,
            ..self
        }
    }

    /// Every state also goes over TCP (see the field).
    pub fn with_record(self) -> Self {
        Self {
            record: true,
            ..self
        }
    }

    /// How long the wait may block: 0 while a reply is due, else until the next emulated
    /// datagram or resend.
    pub fn timeout_ns(&self, udp: &Udp, now: u64) -> u64 {
        if now < self.poll_until {
            return 0;
        }
        let resend_due = self.resend.as_ref().and_then(|r| r.due_ns);
        link::timeout_ns(udp, now).min(resend_due.map_or(u64::MAX, |d| d.saturating_sub(now)))
    }

    /// The plant's states out as datagrams (the final one over TCP). In realtime only the newest
    /// of a wake-up goes out: the older ones of a backlog (this bridge was held up) are past their
    /// budget, and sent together they made the far controller answer each in a burst whose
    /// replies overflowed this side's socket, so states it had answered were recorded as
    /// unanswered and the run did not replay. A state not sent is not answered: the record's
    /// "missed" is then what happened. Lockstep sends each (each awaits its reply).
    pub fn states(
        &mut self,
        (state, state_ready): (&ipc::StateIn, &ipc::Wake),
        udp: &mut Udp,
        tcp: &mut Tcp,
    ) -> Result<()> {
        state_ready.try_wait().ipc("drain state-ready")?;
        let mut newest: Option<StateMsg> = None;
        while let Some(st) = state.receive().ipc("receive state")? {
            if st.flags & wire::STATE_FINAL != 0 {
                if let Some(n) = newest.take() {
                    self.send_state(&n, udp)?;
                }
                tcp.send(Kind::Final, &[bytes_of(&st)])?;
                self.final_sent_ns.get_or_insert(rt::now_ns());
                continue;
            }
            if self.record {
                tcp.queue(Kind::State, &[bytes_of(&st)])?;
            }
            self.newest_state = self.newest_state.max(Some(st.tick));
            if self.direct {
                continue;
            }
            if self.resend.is_some() {
                self.send_state(&st, udp)?;
            } else if newest.replace(st).is_some() {
                self.stale += 1;
            }
        }
        if let Some(n) = newest {
            self.send_state(&n, udp)?;
        }
        Ok(())
    }

    /// One state out as a datagram.
    fn send_state(&mut self, st: &StateMsg, udp: &mut Udp) -> Result<()> {
        self.last_state = (st.tick, st.t_poll_until_ns);
        let now = rt::now_ns();
        udp.send(Kind::State, &[bytes_of(st)], now)?;
        self.poll_until = now + self.spin_ns;
        if let Some(r) = &mut self.resend {
            r.state = *st;
            r.due_ns = Some(now + RESEND_NS);
        }
        Ok(())
    }

    /// The controller's replies from the link, republished on the plant's clock: `t_publish_ns`
    /// = now (their arrival here), `t_state_rx_ns` = now less the residence on the controller's
    /// host. Returns whether any came.
    pub fn torques(
        &mut self,
        (torque, torque_ready): (&ipc::TorqueOut, &ipc::Ping),
        udp: &mut Udp,
    ) -> Result<bool> {
        let mut any = false;
        while let Some((kind, p)) = udp.recv()? {
            any = true;
            if kind != Kind::Torque {
                continue;
            }
            let mut res = Ok(());
            let (last_state, resend) = (self.last_state, &mut self.resend);
            let newest_sent = (last_state.0 != u64::MAX).then_some(last_state.0);
            let gap = self.inbox.take(p, newest_sent, |t, residence| {
                if res.is_ok() {
                    res = republish((torque, torque_ready), t, residence, last_state, resend);
                }
            });
            res?;
            if let Some(g) = gap.filter(|_| self.recall) {
                self.recalls.hole(g);
            }
            self.poll_until = 0;
        }
        Ok(any)
    }

    /// One turn of the loop after the wait: the plant's states out (`state_in`: its event
    /// came), the replies in (`udp_in`), the held datagrams and a due resend out.
    pub fn turn(
        &mut self,
        ports: &ControllerEnds<'_>,
        (state_in, udp_in): (bool, bool),
        udp: &mut Udp,
        tcp: &mut Tcp,
    ) -> Result<()> {
        if self.direct {
            // The plant does not wake this side for each state: look every turn.
            return self.states((ports.0, ports.2), udp, tcp);
        }
        if state_in {
            self.states((ports.0, ports.2), udp, tcp)?;
        }
        if udp_in {
            self.torques((ports.1, ports.3), udp)?;
        }
        udp.flush(rt::now_ns())?;
        self.resend(udp)
    }

    /// Lockstep: sends the state awaiting its reply again if it is due.
    pub fn resend(&mut self, udp: &mut Udp) -> Result<()> {
        if let Some(r) = &mut self.resend
            && let Some(due) = r.due_ns
            && rt::now_ns() >= due
        {
            let now = rt::now_ns();
            r.due_ns = Some(now + RESEND_NS);
            udp.send(Kind::State, &[bytes_of(&r.state)], now)?;
            self.resent += 1;
        }
        Ok(())
    }

    /// A RECALL for each new hole, queued on the control connection (off the tick path: a hole
    /// is rare, and its frame is 16 bytes).
    pub fn recall_out(&mut self, tcp: &mut Tcp) -> Result<()> {
        if !self.recalls.busy() {
            return Ok(());
        }
        self.recalls
            .ask(rt::now_ns(), |p| tcp.queue(Kind::Recall, &[p]))
    }

    /// A RECALLED frame: its replies republished as any late reply (the plant drops a reply to
    /// an earlier tick as late, the supervisor files it with its tick), the ticks of those it
    /// lacks to `unknown` (first, last).
    pub fn recalled(
        &mut self,
        p: &[u8],
        (torque, torque_ready): (&ipc::TorqueOut, &ipc::Ping),
        unknown: impl FnMut(u64, u64),
    ) -> Result<()> {
        let (last_state, resend) = (self.last_state, &mut self.resend);
        let newest_sent = (last_state.0 != u64::MAX).then_some(last_state.0);
        let mut res = Ok(());
        self.recalls.answered(
            p,
            (&mut self.inbox, newest_sent),
            |t, residence| {
                if res.is_ok() {
                    res = republish((torque, torque_ready), t, residence, last_state, resend);
                }
            },
            unknown,
        );
        res
    }
}

/// Publishes the controller's reply `t` on the plant's clock (`residence` ns: its time on the
/// controller's host) and wakes the plant unless it polls for it (`last_state`: the tick and
/// `t_poll_until_ns` of the last state sent); a lockstep resend of its state is called off.
fn republish(
    (torque, torque_ready): (&ipc::TorqueOut, &ipc::Ping),
    mut t: TorqueMsg,
    residence: u64,
    last_state: (u64, u64),
    resend: &mut Option<Resend>,
) -> Result<()> {
    let now = rt::now_ns();
    t.t_publish_ns = now;
    t.t_state_rx_ns = now.saturating_sub(residence);
    // This side blocks on the state event: the plant must always notify it.
    t.t_poll_until_ns = 0;
    torque.send_copy(t).ipc("publish torque")?;
    if let Some(r) = resend
        && r.state.tick == t.tick
    {
        r.due_ns = None;
    }
    let poll_until = if last_state.0 == t.tick {
        last_state.1
    } else {
        0
    };
    if ipc::published_needs_notify(poll_until) {
        torque_ready.notify().ipc("notify torque")?;
    }
    Ok(())
}

/// The controller's host: states in, replies out (see the module).
pub struct ControllerHost {
    /// START has been published here.
    pub started: bool,
    /// A state that came before START (the datagram overtook the TCP frame).
    stash: Option<StateMsg>,
    /// The newest state published here that a reply is owed for (None before the first).
    owed: Option<u64>,
    /// The controller's last `t_poll_until_ns` (this host's clock).
    controller_poll_until: u64,
    /// How long to poll for the reply after publishing a state, ns.
    spin_ns: u64,
    /// Poll (do not block) until then: a reply is due.
    poll_until: u64,
    /// The last replies sent (with their residences), each datagram carrying the two before
    /// it too; sent again for a state the other side sends again (lockstep, after a loss).
    replies: Outbox,
    /// When each of the last [`ARRIVALS`] states arrived: (tick, ns) at slot tick % ARRIVALS, so
    /// a reply to an older state still gets its residence here.
    arrivals: [(u64, u64); ARRIVALS],
    /// Move the states' time stamps onto this host's clock: where the supervisor observes them
    /// on this host (`--plant-remote`).
    local_stamps: bool,
    /// The offset that moves them (see [`Offset`]).
    offset: Offset,
    /// The last state published here (the one to release the controller with if the link dies).
    pub last_state: Option<StateMsg>,
    /// The ticks of the last [`RECENT`] states published here (slot: tick % RECENT).
    recent: [u64; RECENT],
    /// States of a backlog not published: a newer one that came with them went instead.
    pub stale: u64,
    /// The controller took the link's socket (the direct path): the states published here are
    /// the record's, and only the final one wakes the controller.
    pub quiet: bool,
    /// The plant on the other host took its socket while this side relays the controller (one
    /// that speaks only iceoryx2): a copy of each reply for the record there.
    pub copies: Option<Copies>,
}

/// Bytes queued on the control connection above which a recall waits for the next turn.
const RECALL_ROOM: usize = 1 << 20;

pub use deltaloop_link::offset::Offset;

/// States whose arrival time a [`ControllerHost`] keeps.
const ARRIVALS: usize = 64;

/// States a [`ControllerHost`] remembers having published: more than a remote plant's near side
/// holds copies of (1024), so a copy is never taken for unpublished because it is old
/// (regression: 256, and a TCP retransmission of 200 ms had every copy published twice).
pub const RECENT: usize = 4096;

impl ControllerHost {
    pub fn new(spin_ns: u64, local_stamps: bool) -> Self {
        Self {
            started: false,
            stash: None,
            owed: None,
            controller_poll_until: 0,
            spin_ns,
            poll_until: 0,
            replies: Outbox::default(),
            arrivals: [(u64::MAX, 0); ARRIVALS],
            local_stamps,
            offset: Offset::default(),
            last_state: None,
            recent: [u64::MAX; RECENT],
            stale: 0,
            quiet: false,
            copies: None,
        }
    }

    /// Whether state `tick` has been published here (among the last [`RECENT`]).
    pub fn published(&self, tick: u64) -> bool {
        self.recent[(tick % RECENT as u64) as usize] == tick
    }

    /// The newest tick published here.
    pub fn newest(&self) -> Option<u64> {
        self.last_state.map(|s| s.tick)
    }

    /// Whether a reply is due now (poll, do not block).
    pub fn polling(&self, now: u64) -> bool {
        now < self.poll_until
    }

    /// How long the wait may block.
    pub fn timeout_ns(&self, udp: &Udp, now: u64) -> u64 {
        if self.polling(now) {
            0
        } else {
            link::timeout_ns(udp, now)
        }
    }

    /// One turn of the loop after the wait: the controller's replies out (`torque_in`: its
    /// event came, or a reply is due), the states from the link in (`udp_in`), the held
    /// datagrams out. Returns whether a datagram came.
    pub fn turn(
        &mut self,
        ports: &PlantEnds<'_>,
        (torque_in, udp_in): (bool, bool),
        udp: &mut Udp,
        tcp: &mut Tcp,
    ) -> Result<bool> {
        if torque_in || self.polling(rt::now_ns()) {
            self.torques((ports.1, ports.3), udp, tcp)?;
        }
        if let Some(c) = &mut self.copies {
            c.flush(tcp)?;
        }
        let heard = udp_in && self.states((ports.0, ports.2), udp)?;
        udp.flush(rt::now_ns())?;
        Ok(heard)
    }

    /// A RECALL from the other side, answered by [`ControllerHost::answer_recalls`].
    pub fn recall(&mut self, p: &[u8]) {
        self.replies.recall(p);
    }

    /// Answers the oldest recall held from the ring of replies, if the control connection has
    /// room (one per turn: a recall copies at most the ring, 600 KiB).
    pub fn answer_recalls(&mut self, tcp: &mut Tcp) -> Result<()> {
        if tcp.pending() > RECALL_ROOM {
            return Ok(());
        }
        self.replies
            .answer(|parts| tcp.queue(Kind::Recalled, parts))
    }

    /// Recalls refused (malformed, beyond the ring, too many at once).
    pub fn refused_recalls(&self) -> u64 {
        self.replies.refused_recalls
    }

    /// Whether a state is out to the controller and not yet answered.
    pub fn awaiting_reply(&self) -> bool {
        self.owed.is_some() && self.replies.newest_tick() != self.owed
    }

    /// The controller's replies, out as datagrams with the residence here.
    pub fn torques(
        &mut self,
        (torque, torque_ready): (&ipc::TorqueIn, &ipc::Wake),
        udp: &mut Udp,
        tcp: &mut Tcp,
    ) -> Result<()> {
        torque_ready.try_wait().ipc("drain torque-ready")?;
        while let Some(t) = torque.receive().ipc("receive torque")? {
            self.controller_poll_until = t.t_poll_until_ns;
            self.poll_until = 0;
            let now = rt::now_ns();
            let (tick, at) = self.arrivals[(t.tick % ARRIVALS as u64) as usize];
            let residence = if tick == t.tick {
                now.saturating_sub(at)
            } else {
                t.t_publish_ns.saturating_sub(t.t_state_rx_ns)
            };
            let payload = self.replies.push(&t, residence);
            udp.send(Kind::Torque, &[payload], now)?;
            if let Some(c) = &mut self.copies {
                c.push(&t, residence, tcp)?;
            }
        }
        Ok(())
    }

    /// The plant's states from the link, published here. Returns whether any datagram came.
    /// Where nothing records them here (`--controller-remote`), only the newest of those that
    /// came together is published: the others (a backlog, after this bridge or its host was
    /// held up) are past their budget, and the controller answering each sent a burst of replies
    /// that overflowed the other side's socket (see [`PlantHost::states`]).
    pub fn states(&mut self, ports: StatePorts<'_>, udp: &mut Udp) -> Result<bool> {
        let mut any = false;
        let mut newest: Option<StateMsg> = None;
        while let Some((kind, p)) = udp.recv()? {
            any = true;
            if kind != Kind::State {
                continue;
            }
            let Some(s) = bytes::read::<StateMsg>(p) else {
                continue;
            };
            if self.replies.newest_tick() == Some(s.tick) {
                // Sent again: its reply was lost on the way back.
                let now = rt::now_ns();
                udp.send(Kind::Torque, &[self.replies.payload()], now)?;
            } else if self.started && self.published(s.tick) {
                // Sent again while the controller is still on it (it answers once), or published
                // already (its copy over TCP came first).
            } else if !self.started {
                self.stash = Some(s);
            } else if self.local_stamps {
                self.publish_state(ports, s)?;
            } else if let Some(n) = newest.filter(|n| n.tick >= s.tick) {
                // Older than one that came with it (the same state twice is no backlog).
                self.stale += u64::from(n.tick > s.tick);
            } else if newest.replace(s).is_some() {
                self.stale += 1;
            }
        }
        if let Some(s) = newest {
            self.publish_state(ports, s)?;
        }
        Ok(any)
    }

    /// START has been published here: a state that came before it goes out now.
    pub fn start(&mut self, ports: StatePorts<'_>) -> Result<()> {
        self.started = true;
        if let Some(s) = self.stash.take() {
            self.publish_state(ports, s)?;
        }
        Ok(())
    }

    /// Publishes a state here (the final one too) and wakes the controller unless it polls.
    pub fn publish_state(
        &mut self,
        (state, state_ready): StatePorts<'_>,
        mut s: StateMsg,
    ) -> Result<()> {
        // This side polls for the reply until poll_until, then blocks on the torque event
        // (docs/protocol.md §6.1, on this host's clock).
        let now = rt::now_ns();
        self.poll_until = now + self.spin_ns;
        s.t_poll_until_ns = self.poll_until;
        if self.local_stamps {
            // Its publication here is its arrival: what the controller's latency counts from.
            self.offset.restamp(&mut s, now);
        }
        // A reply is owed for the newest state only (not the final one, nor an older one
        // published late for the record).
        if s.flags & wire::STATE_FINAL == 0 && self.owed.is_none_or(|o| s.tick > o) {
            self.owed = Some(s.tick);
            self.arrivals[(s.tick % ARRIVALS as u64) as usize] = (s.tick, now);
        }
        self.recent[(s.tick % RECENT as u64) as usize] = s.tick;
        if self.last_state.is_none_or(|l| l.tick <= s.tick) {
            self.last_state = Some(s);
        }
        state.send_copy(s).ipc("publish state")?;
        let last = s.flags & wire::STATE_FINAL != 0;
        if (self.quiet && last)
            || (!self.quiet && ipc::published_needs_notify(self.controller_poll_until))
        {
            state_ready.notify().ipc("notify state")?;
        }
        Ok(())
    }
}

/// The far controller's replies for the record on the plant's host, when the plant there took
/// the link's socket (the direct path, `--controller-remote`): each reply numbered, with its
/// residence here, gathered into REPLIES frames ([`Kind::Replies`]). Pre-allocated.
pub struct Copies {
    seq: u64,
    buf: Box<[u8]>,
    n: usize,
}

impl Default for Copies {
    fn default() -> Self {
        Self {
            seq: 0,
            buf: vec![0; crate::frame::MAX_REPLIES * crate::replies::ENTRY].into_boxed_slice(),
            n: 0,
        }
    }
}

impl Copies {
    /// Reply `t` with its `residence` (ns) into the next frame (the full frame goes out first).
    pub fn push(&mut self, t: &TorqueMsg, residence: u64, tcp: &mut Tcp) -> Result<()> {
        if self.n == crate::frame::MAX_REPLIES {
            self.flush(tcp)?;
        }
        let e = crate::replies::ENTRY;
        let at = self.n * e;
        self.buf[at..at + e - 16].copy_from_slice(bytes_of(t));
        self.buf[at + e - 16..at + e - 8].copy_from_slice(&residence.to_ne_bytes());
        self.buf[at + e - 8..at + e].copy_from_slice(&self.seq.to_ne_bytes());
        self.seq += 1;
        self.n += 1;
        Ok(())
    }

    /// The replies gathered, out in one frame (queued on the control connection).
    pub fn flush(&mut self, tcp: &mut Tcp) -> Result<()> {
        if self.n > 0 {
            let e = crate::replies::ENTRY;
            tcp.queue(Kind::Replies, &[&self.buf[..self.n * e]])?;
            self.n = 0;
        }
        Ok(())
    }

    /// Every reply the controller published on this host since the last call (the direct path:
    /// its residence from the controller's own stamps), out.
    pub fn take(&mut self, torque: &ipc::TorqueIn, tcp: &mut Tcp) -> Result<()> {
        while let Some(t) = torque.receive().ipc("receive torque")? {
            self.push(&t, t.t_publish_ns.saturating_sub(t.t_state_rx_ns), tcp)?;
        }
        self.flush(tcp)
    }
}

/// How far behind the plant's newest state a reply's copy may come and still find its tick
/// open in the record, ticks: the supervisor's queues and its wait for a copy the plant's
/// telemetry says is on its way ([`ipc::OBSERVER_BUFFER`]).
pub const RECORD_HORIZON: u64 = ipc::OBSERVER_BUFFER as u64;

/// A REPLIES frame's replies filed for the record here (the direct path, `--controller-remote`),
/// on this host's clock as the relay republished them, waking no one: the plant took each from
/// its own socket. Malformed entries are skipped. Returns how many came [`RECORD_HORIZON`] or
/// more ticks behind `newest_state` (the plant's newest state here): too late for the record,
/// which had finished their ticks (this bridge was held up).
pub fn file_replies(p: &[u8], torque: &ipc::TorqueOut, newest_state: Option<u64>) -> Result<u64> {
    let mut late = 0;
    for i in 0..p.len() / crate::replies::ENTRY {
        let Some(e) = crate::replies::entry(p, i) else {
            continue;
        };
        if newest_state.is_some_and(|n| n >= e.msg.tick.saturating_add(RECORD_HORIZON)) {
            late += 1;
        }
        let mut t = e.msg;
        let now = rt::now_ns();
        t.t_publish_ns = now;
        t.t_state_rx_ns = now.saturating_sub(e.residence_ns);
        t.t_poll_until_ns = 0;
        torque.send_copy(t).ipc("publish torque")?;
    }
    Ok(late)
}

/// Republishes what the controller on the other host said (frame payload `p`), as the
/// controller, with its tick and text, if it is something a controller may say; on
/// CONTROLLER_ERROR it wakes the plant, which reads it when it wakes (as the controller itself
/// does), or a lockstep plant would wait out its silence. Both stand-ins of a far controller's
/// words call this: the near side, and the far side of a remote plant.
pub fn say_as_controller(
    p: &[u8],
    control: &ipc::ControlOut,
    torque_ready: &ipc::Ping,
) -> Result<()> {
    let Some(c) = bytes::read::<ControlMsg>(p) else {
        return Ok(());
    };
    if !c.kind().is_some_and(|k| k.said_by_controller()) {
        return Ok(());
    }
    let said = ControlMsg {
        from: Sender::Controller as u32,
        ..c
    };
    control.send_copy(said).ipc("send controller control")?;
    if c.kind() == Some(ControlKind::ControllerError) {
        torque_ready.notify().ipc("notify torque")?;
    }
    Ok(())
}

/// The ports a [`ControllerHost`] publishes states on: `state` and `state-ready`.
pub type StatePorts<'a> = (&'a ipc::StateOut, &'a ipc::Ping);

/// The controller's loop ports, which a [`PlantHost`] holds: `state`, `torque`, `state-ready`,
/// `torque-ready` (as [`ipc::ControllerLoop`], borrowed).
pub type ControllerEnds<'a> = (
    &'a ipc::StateIn,
    &'a ipc::TorqueOut,
    &'a ipc::Wake,
    &'a ipc::Ping,
);

/// The plant's loop ports, which a [`ControllerHost`] holds: `state`, `torque`, `state-ready`,
/// `torque-ready` (as [`ipc::PlantLoop`], borrowed).
pub type PlantEnds<'a> = (
    &'a ipc::StateOut,
    &'a ipc::TorqueIn,
    &'a ipc::Ping,
    &'a ipc::Wake,
);

#[cfg(test)]
mod tests {
    use super::*;

    /// Regression (`--plant-remote`): each state's stamps moved by its own delay, so the states a
    /// stalled near bridge published late moved every later deadline by the stall, the
    /// controller's schedule followed, and the run ended in a silence fault. The offset is the
    /// smallest of the recent delays: a late state does not move it; a lasting change of the
    /// clocks' offset (drift) is followed within two blocks.
    #[test]
    fn regression_a_late_state_does_not_move_the_clock_offset() {
        let mut o = Offset::default();
        for _ in 0..100 {
            assert_eq!(o.add(1_000_000), 1_000_000);
        }
        // A 100 ms stall: the backlog arrives up to 100 ms late.
        for late in (0..330).rev() {
            assert_eq!(o.add(1_000_000 + late * 300_000), 1_000_000);
        }
        assert_eq!(o.add(1_000_000), 1_000_000);
        // The clocks drift 1 µs apart: followed once the older blocks are out of the window.
        let mut now = 0;
        for _ in 0..(2 * deltaloop_link::offset::OFFSET_BLOCK + 1) {
            now = o.add(1_001_000);
        }
        assert_eq!(now, 1_001_000);
    }
    use crate::emulation::Emulation;
    use crate::seal::{End, Session};
    use std::net::{TcpListener, TcpStream, UdpSocket};

    /// The near side's link to a stand-in far side: (near UDP, near TCP, far UDP, far's TCP end).
    fn link() -> (Udp, Tcp, Udp, TcpStream) {
        let session = Session::generate().unwrap();
        let (a, b) = (
            UdpSocket::bind("127.0.0.1:0").unwrap(),
            UdpSocket::bind("127.0.0.1:0").unwrap(),
        );
        a.connect(b.local_addr().unwrap()).unwrap();
        b.connect(a.local_addr().unwrap()).unwrap();
        let l = TcpListener::bind("127.0.0.1:0").unwrap();
        let far_tcp = TcpStream::connect(l.local_addr().unwrap()).unwrap();
        let near_tcp = l.accept().unwrap().0;
        (
            Udp::sealed(a, &session, End::Near, Emulation::default()).unwrap(),
            Tcp::new(near_tcp, &session, End::Near).unwrap(),
            Udp::sealed(b, &session, End::Far, Emulation::default()).unwrap(),
            far_tcp,
        )
    }

    /// The ticks of the state datagrams `far` receives.
    fn states_heard(far: &mut Udp) -> Vec<u64> {
        std::thread::sleep(std::time::Duration::from_millis(20));
        let mut got = Vec::new();
        while let Some((kind, p)) = far.recv().unwrap() {
            assert_eq!(kind, Kind::State);
            got.push(bytes::read::<StateMsg>(p).unwrap().tick);
        }
        got
    }

    /// Regression: a near bridge held up for 100 ms found 330 of the plant's states waiting and
    /// sent them all at once; the far controller answered each, the burst of replies overflowed
    /// this side's socket, and states the controller had answered were recorded as unanswered
    /// (the run did not replay). In realtime only the newest of a backlog goes out (the others
    /// are counted); in lockstep each state awaits its reply, and each goes out.
    #[test]
    fn regression_a_backlog_of_states_is_not_sent_on_in_a_burst() {
        let run_id = format!("sides-test-{}", std::process::id());
        let node = ipc::node("plant", &run_id).unwrap();
        let plant = ipc::plant_loop(&node, &run_id, 16).unwrap();
        let near = ipc::controller_loop(&node, &run_id, ipc::RELAY_BUFFER).unwrap();
        let ends = (&near.0, &near.1, &near.2, &near.3);
        for lockstep in [false, true] {
            let (mut udp, mut tcp, mut far, _far_tcp) = link();
            let mut host = PlantHost::new(0, lockstep);
            // Fewer than a socket takes at once (it dropped 134 of a burst of 300 here).
            for tick in 0..100 {
                plant
                    .0
                    .send_copy(StateMsg {
                        tick,
                        ..StateMsg::default()
                    })
                    .unwrap();
            }
            host.turn(&ends, (true, false), &mut udp, &mut tcp).unwrap();
            let heard = states_heard(&mut far);
            if lockstep {
                assert_eq!(heard, (0..100).collect::<Vec<_>>());
                assert_eq!(host.counts().stale, 0);
            } else {
                assert_eq!(heard, [99]);
                assert_eq!(host.counts().stale, 99);
            }
        }
    }

    /// Regression: the far bridge of a remote controller published only the newest of the
    /// states that came together, and dropped the others uncounted, while the protocol says
    /// they are counted in its closing line (as the plant's host counts its own). Ten states in
    /// one wake-up, one of them twice: the newest is published, the nine older ones counted,
    /// the repeat not.
    #[test]
    fn regression_the_controllers_host_counts_the_states_of_a_backlog_it_drops() {
        let run_id = format!("sides-stale-{}", std::process::id());
        let node = ipc::node("plant", &run_id).unwrap();
        let ends = ipc::plant_loop(&node, &run_id, ipc::RELAY_BUFFER).unwrap();
        let controller = ipc::controller_loop(&node, &run_id, 16).unwrap();
        let (mut near, _tcp, mut far, _far_tcp) = link();
        let mut host = ControllerHost::new(0, false);
        host.start((&ends.0, &ends.2)).unwrap();
        for tick in (0..10).chain([9]) {
            let s = StateMsg {
                tick,
                ..StateMsg::default()
            };
            near.send(Kind::State, &[bytes_of(&s)], rt::now_ns())
                .unwrap();
        }
        std::thread::sleep(std::time::Duration::from_millis(20));
        assert!(host.states((&ends.0, &ends.2), &mut far).unwrap());
        let mut published = Vec::new();
        while let Some(s) = controller.0.receive().unwrap() {
            published.push(s.tick);
        }
        assert_eq!(published, [9]);
        assert_eq!(host.stale, 9);
    }

    /// A burst of six reply datagrams lost between the far side and a tap on the way (more than
    /// the copies bring back): the near side sees the hole from the numbers, recalls it over
    /// the sealed control connection, the far side answers from its ring, and the plant's host
    /// gets every reply the far controller sent, once each, the recalled ones after the reply
    /// that revealed the hole (as late replies).
    #[test]
    fn a_burst_of_lost_replies_is_recalled_over_the_control_connection() {
        let session = Session::generate().unwrap();
        let tap = UdpSocket::bind("127.0.0.1:0").unwrap();
        let (n, f) = (
            UdpSocket::bind("127.0.0.1:0").unwrap(),
            UdpSocket::bind("127.0.0.1:0").unwrap(),
        );
        n.connect(tap.local_addr().unwrap()).unwrap();
        f.connect(tap.local_addr().unwrap()).unwrap();
        let to_near = n.local_addr().unwrap();
        let mut near_udp = Udp::sealed(n, &session, End::Near, Emulation::default()).unwrap();
        let mut far_udp = Udp::sealed(f, &session, End::Far, Emulation::default()).unwrap();
        let l = TcpListener::bind("127.0.0.1:0").unwrap();
        let far_stream = TcpStream::connect(l.local_addr().unwrap()).unwrap();
        let mut near_tcp = Tcp::new(l.accept().unwrap().0, &session, End::Near).unwrap();
        let mut far_tcp = Tcp::new(far_stream, &session, End::Far).unwrap();

        // Each host's iceoryx2 ports (two runs: the hosts share nothing but the link).
        let pid = std::process::id();
        let (far_run, near_run) = (format!("recall-far-{pid}"), format!("recall-near-{pid}"));
        let far_node = ipc::node("plant", &far_run).unwrap();
        let far_plant_ends = ipc::plant_loop(&far_node, &far_run, ipc::RELAY_BUFFER).unwrap();
        let controller = ipc::controller_loop(&far_node, &far_run, 16).unwrap();
        let near_node = ipc::node("controller", &near_run).unwrap();
        let near_ends = ipc::controller_loop(&near_node, &near_run, ipc::RELAY_BUFFER).unwrap();
        let plant = ipc::plant_loop(&near_node, &near_run, 64).unwrap();
        let fe = &far_plant_ends;
        let (far_ends, ne) = ((&fe.0, &fe.1, &fe.2, &fe.3), &near_ends);
        let ends = (&ne.0, &ne.1, &ne.2, &ne.3);
        let mut near = PlantHost::new(0, false).with_recall();
        let mut far = ControllerHost::new(0, false);

        // The plant's state 19 went out (the replies below answer states sent).
        plant
            .0
            .send_copy(StateMsg {
                tick: 19,
                ..StateMsg::default()
            })
            .unwrap();
        near.turn(&ends, (true, false), &mut near_udp, &mut near_tcp)
            .unwrap();
        std::thread::sleep(std::time::Duration::from_millis(20));
        let mut buf = [0u8; 2048];
        while tap.set_nonblocking(true).is_ok() && tap.recv(&mut buf).is_ok() {}
        // Replies 0..20 from the far controller; datagrams 5..=10 lost on the way: 9 and 10 come
        // back as copies in 11's, 5..=8 are beyond the copies.
        for tick in 0..20u64 {
            controller
                .1
                .send_copy(TorqueMsg {
                    tick,
                    tau: [tick as f64; 3],
                    ..TorqueMsg::default()
                })
                .unwrap();
            far.torques((far_ends.1, far_ends.3), &mut far_udp, &mut far_tcp)
                .unwrap();
            std::thread::sleep(std::time::Duration::from_millis(2));
            let n = tap.recv(&mut buf).unwrap();
            if !(5..=10).contains(&tick) {
                tap.send_to(&buf[..n], to_near).unwrap();
            }
        }
        std::thread::sleep(std::time::Duration::from_millis(20));
        near.torques((ends.1, ends.3), &mut near_udp).unwrap();
        let heard = |plant: &ipc::PlantLoop| {
            let mut got = Vec::new();
            while let Some(s) = plant.1.receive().unwrap() {
                assert_eq!(s.tau[0], s.tick as f64);
                got.push(s.tick);
            }
            got
        };
        let before: Vec<u64> = heard(&plant);
        assert_eq!(
            before,
            [0, 1, 2, 3, 4, 9, 10, 11, 12, 13, 14, 15, 16, 17, 18, 19]
        );
        assert_eq!(near.counts().lost, 4);

        // The recall, its answer from the ring, the replies published.
        near.recall_out(&mut near_tcp).unwrap();
        near_tcp.flush().unwrap();
        std::thread::sleep(std::time::Duration::from_millis(20));
        far_tcp
            .poll(|k, p| {
                assert_eq!(k, Kind::Recall);
                far.recall(p);
                Ok(())
            })
            .unwrap();
        far.answer_recalls(&mut far_tcp).unwrap();
        far_tcp.flush().unwrap();
        std::thread::sleep(std::time::Duration::from_millis(20));
        let mut unknown = Vec::new();
        near_tcp
            .poll(|k, p| {
                assert_eq!(k, Kind::Recalled);
                near.recalled(p, (ends.1, ends.3), |a, b| unknown.push((a, b)))
            })
            .unwrap();
        assert_eq!(heard(&plant), [5, 6, 7, 8]);
        assert!(unknown.is_empty(), "{unknown:?}");
        let c = near.counts();
        assert_eq!((c.recalled, c.unknown, c.refused_recalls), (4, 0, 0));
        assert!(!near.recalls.busy());
        assert_eq!(far.refused_recalls(), 0);
    }
}
