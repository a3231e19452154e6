//! The near side (`deltaloop-bridge near`): started by the supervisor in place of the controller
//! (`deltaloop run --controller-remote`), it opens the controller's ports on this host, waits for
//! the far side (`deltaloop join`) to connect, and carries the run across: states out as UDP
//! datagrams, torques back in, run control, reference chunks and the final state over TCP. To the
//! plant and the supervisor it is the controller: READY and ARMED are sent when the far
//! controller sends them, its replies are republished here, and it exits as the far controller
//! exited.
//!
//! Clocks: a reply is republished with `t_publish_ns` = when it reached this host (this host's
//! clock, the plant's), so the plant judges the budget and the arrival on its own clock; its
//! `t_state_rx_ns` is that time less the far side's residence (state in to reply out, measured on
//! the far clock), so `controller_compute` is the far residence and `state_to_controller` the
//! link's round trip without it (docs/protocol.md §14).

use crate::frame::{self, Hello, Kind, bytes_of, bytes_of_slice};
use crate::link::{self, Emulation, Tcp, Udp};
use crate::replies::Inbox;
use anyhow::{Context, Result, bail};
use deltaloop_config::Law;
use deltaloop_transport::args::LoopArgs;
use deltaloop_transport::exit::{EXIT_FAULT, EXIT_STOPPED};
use deltaloop_transport::ipc::{self, ControlPorts, IpcContext};
use deltaloop_transport::rt;
use deltaloop_transport::wire::{self, ControlKind, ControlMsg, Sender, StateMsg, TorqueMsg};
use std::net::{SocketAddr, TcpListener, UdpSocket};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

/// `deltaloop-bridge near`.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// Where to wait for the far side: HOST:PORT of this host (TCP for the control plane, UDP for
    /// the loop, the same port).
    #[arg(long, value_parser = crate::parse_endpoint)]
    pub listen: SocketAddr,
    #[command(flatten)]
    pub emu: crate::EmuArgs,
    #[command(flatten)]
    pub run: LoopArgs,
    /// The control law (passed on to the far controller).
    #[arg(long, value_parser = Law::parse)]
    pub law: Law,
}

/// How the far side ended: its exit code and last line.
struct FarEnd {
    code: u8,
    line: String,
}

/// The controller's side of the run on this host, which this bridge holds in its place.
type Ports = ipc::ControllerPorts;

/// Runs the near side; returns the exit code and its one line (None: completed).
pub fn run(a: &Args, term: &AtomicBool) -> Result<(u8, Option<String>)> {
    let config = std::fs::read_to_string(&a.run.config)
        .with_context(|| format!("cannot read --config {}", a.run.config.display()))?;
    let run_id = &a.run.run_id;
    let key = frame::run_key(run_id);
    let emu = a.emu.emulation()?;
    let spin_ns = crate::spin_ns(&a.run.config, a.run.mode, a.emu.link_spin_us)?;
    let ports = Ports::open(run_id, ipc::RELAY_BUFFER)?;
    let listener = TcpListener::bind(a.listen)
        .with_context(|| format!("cannot listen on --listen {} (TCP)", a.listen))?;
    let udp = UdpSocket::bind(a.listen)
        .with_context(|| format!("cannot bind --listen {} (UDP)", a.listen))?;
    listener.set_nonblocking(true)?;
    // The far side connects: wait for it as long as a handshake step may take.
    let end = rt::now_ns() + ipc::HANDSHAKE_TIMEOUT_NS;
    let (stream, peer) = loop {
        match listener.accept() {
            Ok(s) => break s,
            Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => {}
            Err(e) => return Err(e).context("accept the far side"),
        }
        if stopped(&ports.control, term)? {
            return Ok((
                EXIT_STOPPED,
                Some("stopped before the far side joined".into()),
            ));
        }
        if rt::now_ns() > end {
            bail!(
                "no far side joined at {} within {} s (run `deltaloop join {} --role controller` on the other host)",
                a.listen,
                ipc::HANDSHAKE_TIMEOUT_NS / 1_000_000_000,
                a.listen
            );
        }
        std::thread::sleep(Duration::from_millis(5));
    };
    drop(listener);
    let mut tcp = Tcp::new(stream)?;
    let hello = Hello {
        run_id: run_id.clone(),
        mode: a.run.mode.name().to_string(),
        law: a.law.name().to_string(),
        emulation: emu,
        config,
    };
    tcp.send(Kind::Hello, key, &[&hello.encode()])?;
    tcp.set_key(key);
    let mut far_udp = None;
    while far_udp.is_none() {
        tcp.poll(|k, p| {
            if k == Kind::Ack {
                far_udp = frame::read::<u64>(p);
            }
            Ok(())
        })?;
        if tcp.closed {
            bail!("the far side {peer} closed the link during the handshake");
        }
        if rt::now_ns() > end {
            bail!("the far side {peer} did not answer the HELLO");
        }
        if stopped(&ports.control, term)? {
            return Ok((
                EXIT_STOPPED,
                Some("stopped before the far side joined".into()),
            ));
        }
        std::thread::sleep(Duration::from_millis(1));
    }
    let far_port = far_udp.unwrap_or(0);
    let Ok(far_port) = u16::try_from(far_port) else {
        bail!("the far side sent UDP port {far_port} (allowed 1..=65535)");
    };
    udp.connect(SocketAddr::new(peer.ip(), far_port))
        .context("connect the link's UDP socket")?;
    let udp = Udp::new(udp, key, emu)?;
    let mut n = Near {
        ports,
        udp,
        tcp,
        key,
        last_state: (u64::MAX, 0),
        far_end: None,
        final_sent_ns: None,
        stop_sent_ns: None,
        spin_ns,
        poll_until: 0,
        resend: (a.run.mode == deltaloop_config::LoopMode::Lockstep).then_some(Resend {
            state: StateMsg::default(),
            due_ns: None,
        }),
        resent: 0,
        inbox: Inbox::default(),
    };
    let r = n.forward(term);
    n.tcp.flush().ok();
    std::thread::sleep(ipc::LINGER);
    let end = r?;
    if !emu.is_off() || n.resent > 0 || n.inbox.recovered > 0 {
        eprintln!(
            "deltaloop-bridge: {}: {} datagram(s) dropped here, {} state(s) sent again, {} repl(ies) recovered from a later datagram",
            describe(&emu),
            n.udp.emulated_lost,
            n.resent,
            n.inbox.recovered
        );
    }
    if n.udp.refused > 0 {
        eprintln!(
            "deltaloop-bridge: warning: refused {} datagram(s) on the link (first: {})",
            n.udp.refused,
            n.udp.last_refusal.as_deref().unwrap_or("")
        );
    }
    Ok(end)
}

/// Whether the supervisor said STOP (or SIGTERM came), before START.
fn stopped(control: &ControlPorts, term: &AtomicBool) -> Result<bool> {
    let mut stop = term.load(Ordering::Relaxed);
    while let Some(s) = control.1.receive().ipc("receive control")? {
        stop |= s.payload().kind() == Some(ControlKind::Stop);
    }
    Ok(stop)
}

struct Near {
    ports: Ports,
    udp: Udp,
    tcp: Tcp,
    key: u64,
    /// The last state sent: its tick and the plant's `t_poll_until_ns`.
    last_state: (u64, u64),
    far_end: Option<FarEnd>,
    /// When the final state went to the far side.
    final_sent_ns: Option<u64>,
    /// When a STOP (SIGTERM) went to the far side.
    stop_sent_ns: Option<u64>,
    /// How long to poll for the reply after sending a state, ns.
    spin_ns: u64,
    /// Poll (do not block) until then: a reply is due.
    poll_until: u64,
    /// Lockstep only: the state awaiting its reply, sent again every [`RESEND_NS`] until the
    /// reply comes, so a lost datagram costs time, never the run (the far side answers a repeated
    /// state with its cached reply). In realtime a lost state or reply is a miss, as it should be.
    resend: Option<Resend>,
    /// States sent again (lockstep).
    resent: u64,
    /// The replies republished, each once.
    inbox: Inbox,
}

struct Resend {
    state: StateMsg,
    /// When to send it again; None once its reply came.
    due_ns: Option<u64>,
}

/// Lockstep: how long to wait for a reply before sending its state again, ns.
pub const RESEND_NS: u64 = 5_000_000;

/// How long the far side has to report its end after the final state or a STOP, ns: the
/// supervisor gives a controller 1 s after the plant exits.
const FAR_END_WAIT_NS: u64 = 700_000_000;

impl Near {
    fn forward(&mut self, term: &AtomicBool) -> Result<(u8, Option<String>)> {
        loop {
            let now = rt::now_ns();
            let resend_due = self.resend.as_ref().and_then(|r| r.due_ns);
            let timeout = if now < self.poll_until {
                0
            } else {
                link::timeout_ns(&self.udp, now)
                    .min(resend_due.map_or(u64::MAX, |d| d.saturating_sub(now)))
            };
            let mut fds = [
                link::readable(&self.udp.sock),
                link::readable(&self.tcp.stream),
                link::event(&self.ports.state_ready),
            ];
            if self.tcp.pending() > 0 {
                fds[1].events |= libc::POLLOUT;
            }
            link::wait(&mut fds, timeout)?;
            let [udp_in, tcp_in, state_in] = fds.map(|f| f.revents != 0);
            self.forward_control()?;
            if state_in {
                self.states()?;
            }
            if udp_in {
                self.torques()?;
            }
            self.udp.flush(rt::now_ns())?;
            if let Some(r) = &mut self.resend
                && let Some(due) = r.due_ns
                && rt::now_ns() >= due
            {
                let now = rt::now_ns();
                r.due_ns = Some(now + RESEND_NS);
                self.udp.send(Kind::State, &[bytes_of(&r.state)], now)?;
                self.resent += 1;
            }
            self.control_plane(tcp_in)?;
            if let Some(end) = self.far_end.take() {
                let line = (!end.line.is_empty()).then_some(end.line);
                return Ok((
                    end.code,
                    line.or(Some(format!("far side exited {}", end.code))),
                ));
            }
            let now = rt::now_ns();
            if self.tcp.closed {
                return Ok((
                    EXIT_FAULT,
                    Some(
                        "the link's control connection closed before the far side reported its end"
                            .into(),
                    ),
                ));
            }
            if term.load(Ordering::Relaxed) && self.stop_sent_ns.is_none() {
                let stop = ControlMsg::new(ControlKind::Stop, Sender::Supervisor);
                self.tcp.send(Kind::Control, self.key, &[bytes_of(&stop)])?;
                self.stop_sent_ns = Some(now);
            }
            if self.stop_sent_ns.is_some_and(|t| now > t + FAR_END_WAIT_NS) {
                return Ok((
                    EXIT_STOPPED,
                    Some(format!(
                        "stopped by SIGTERM; the far side did not report its end within {} ms (the link is down?)",
                        FAR_END_WAIT_NS / 1_000_000
                    )),
                ));
            }
            if self
                .final_sent_ns
                .is_some_and(|t| now > t + FAR_END_WAIT_NS)
            {
                // The plant has ended the run and released its controller, which is this
                // process: what became of the far one is unknown (the plant's own verdict, e.g.
                // a silent controller, says what happened to the loop).
                eprintln!(
                    "deltaloop-bridge: warning: the far side did not report its end within {} ms of the final state (the link is down?)",
                    FAR_END_WAIT_NS / 1_000_000
                );
                return Ok((0, None));
            }
        }
    }

    /// The plant's states: each out as a datagram; the final one over TCP.
    fn states(&mut self) -> Result<()> {
        self.ports
            .state_ready
            .try_wait(|_| {})
            .ipc("drain state-ready")?;
        while let Some(s) = self.ports.state.receive().ipc("receive state")? {
            let st: &StateMsg = s.payload();
            if st.flags & wire::STATE_FINAL != 0 {
                self.tcp.send(Kind::Final, self.key, &[bytes_of(st)])?;
                self.final_sent_ns.get_or_insert(rt::now_ns());
            } else {
                self.last_state = (st.tick, st.t_poll_until_ns);
                let now = rt::now_ns();
                self.udp.send(Kind::State, &[bytes_of(st)], now)?;
                self.poll_until = now + self.spin_ns;
                if let Some(r) = &mut self.resend {
                    r.state = *st;
                    r.due_ns = Some(now + RESEND_NS);
                }
            }
        }
        Ok(())
    }

    /// The far controller's replies, republished on the plant's clock.
    fn torques(&mut self) -> Result<()> {
        while let Some((kind, p)) = self.udp.recv()? {
            if kind != Kind::Torque {
                continue;
            }
            let mut res = Ok(());
            self.inbox.take(p, |t, residence| {
                if res.is_ok() {
                    res = republish(&self.ports, t, residence, self.last_state, &mut self.resend);
                }
            });
            res?;
            self.poll_until = 0;
        }
        Ok(())
    }

    /// The supervisor's run control out (START with its deadline made relative, STOP). Before the
    /// states of each wake-up: a STOP must reach the far side before the final state it causes.
    fn forward_control(&mut self) -> Result<()> {
        while let Some(s) = self.ports.control.1.receive().ipc("receive control")? {
            let mut c = *s.payload();
            match (c.kind(), c.sender()) {
                (Some(ControlKind::Start), Some(Sender::Supervisor)) => {
                    c.t0_ns = c.t0_ns.saturating_sub(rt::now_ns());
                    self.tcp.send(Kind::Control, self.key, &[bytes_of(&c)])?;
                }
                (Some(ControlKind::Stop), Some(Sender::Supervisor)) => {
                    self.tcp.send(Kind::Control, self.key, &[bytes_of(&c)])?;
                }
                _ => {}
            }
        }
        Ok(())
    }

    /// The reference out, the far side's control, log and end in.
    fn control_plane(&mut self, tcp_in: bool) -> Result<()> {
        // One chunk at a time in flight: the subscriber keeps the rest (REF_RING deep).
        while self.tcp.pending() < 64 * 1024 {
            let Some(chunk) = self.ports.reference.receive().ipc("receive reference")? else {
                break;
            };
            self.tcp.send(
                Kind::Reference,
                self.key,
                &[bytes_of_slice(chunk.payload())],
            )?;
        }
        if self.tcp.pending() > 0 {
            self.tcp.flush()?;
        }
        if !tcp_in {
            return Ok(());
        }
        let (mut said, mut end) = (Vec::new(), None);
        self.tcp.poll(|kind, p| {
            match kind {
                Kind::Control => {
                    if let Some(c) = frame::read::<ControlMsg>(p) {
                        said.push(c);
                    }
                }
                Kind::Log => eprintln!("{}", wire::escape_peer_text(&String::from_utf8_lossy(p))),
                Kind::Exit => {
                    let (code, line) = p.split_at(4);
                    let code = u32::from_ne_bytes([code[0], code[1], code[2], code[3]]);
                    end = Some(FarEnd {
                        code: u8::try_from(code).unwrap_or(EXIT_FAULT),
                        line: wire::escape_peer_text(&String::from_utf8_lossy(line)),
                    });
                }
                _ => {}
            }
            Ok(())
        })?;
        for c in said {
            // Only what a controller may say, as the controller (this process is its stand-in).
            if let Some(kind @ (ControlKind::Ready | ControlKind::Armed)) = c.kind() {
                self.ports
                    .control
                    .0
                    .send_copy(ControlMsg::new(kind, Sender::Controller))
                    .ipc(format!("send {kind:?}"))?;
            }
        }
        if end.is_some() {
            self.far_end = end;
        }
        Ok(())
    }
}

/// Publishes the far controller's reply `t` on the plant's clock (`residence` ns: its time on
/// the far host) and wakes the plant unless it is polling for it; a lockstep resend of its state
/// is called off.
fn republish(
    ports: &Ports,
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
    ports.torque.send_copy(t).ipc("publish torque")?;
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
        ports.torque_ready.notify().ipc("notify torque")?;
    }
    Ok(())
}

/// Exposed for the far side's START: tick 0's deadline on this host's clock, from the relative
/// time on the wire.
pub fn absolute_t0(relative_ns: u64) -> u64 {
    rt::now_ns().saturating_add(relative_ns)
}

/// The emulation in force (for the report line).
pub fn describe(e: &Emulation) -> String {
    format!(
        "emulated link: delay {} µs, jitter {} µs, loss {} ppm, seed {}",
        e.delay_ns / 1000,
        e.jitter_ns / 1000,
        e.loss_ppm,
        e.seed
    )
}
