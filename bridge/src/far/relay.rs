//! The far side's loop once the run started: the process it started ([`FarChild`]), the link
//! around it ([`FarLink`]) and the relay between the process's iceoryx2 ports and the link
//! (controller here: `Far`; plant here: `FarPlant`).

use super::*;

/// The link and the far process: what both roles do around their loop.
pub(super) struct FarLink {
    udp: Udp,
    tcp: Tcp,
    child: FarChild,
    stop_sent: bool,
    /// When the near side closed the control connection.
    near_gone_ns: Option<u64>,
    /// When to look whether the process has exited next.
    next_check: u64,
    /// The run's session, the hand-off to the process and whether it took the link's socket
    /// at START (the direct path: this side then relays no datagram and never reads the socket).
    session: Session,
    handoff: Option<deltaloop_transport::handoff::End>,
    relay: bool,
    direct: bool,
    /// The CPU of the process started here, which this side leaves on the direct path.
    loop_cpu: Option<usize>,
}

impl FarLink {
    /// The link of a run that has started `child`: `relay` if the config asks for the relay
    /// path, `loop_cpu` the CPU of the process (left to it on the direct path).
    pub(super) fn new(
        (udp, tcp): (Udp, Tcp),
        child: FarChild,
        session: Session,
        handoff: deltaloop_transport::handoff::End,
        relay: bool,
        loop_cpu: Option<usize>,
    ) -> Self {
        Self {
            udp,
            tcp,
            child,
            stop_sent: false,
            near_gone_ns: None,
            next_check: 0,
            session,
            handoff: Some(handoff),
            relay,
            direct: false,
            loop_cpu,
        }
    }

    /// Datagrams the emulation dropped on this side.
    fn emulated_lost(&self) -> u64 {
        self.udp.emulated_lost
    }

    /// The wait of one turn: the socket, the control connection, the wake-up `event` and the
    /// process's stderr.
    fn wait(&self, event: &ipc::Wake, timeout_ns: u64) -> Result<[bool; 4]> {
        let err_fd = self
            .child
            .child
            .stderr
            .as_ref()
            .map_or(-1, std::os::fd::AsRawFd::as_raw_fd);
        let mut fds = [
            link::readable(&self.udp.sock),
            link::readable(&self.tcp.stream),
            link::event(event),
            libc::pollfd {
                fd: err_fd,
                events: libc::POLLIN,
                revents: 0,
            },
        ];
        if self.direct {
            fds[0].fd = -1;
        }
        if self.tcp.pending() > 0 {
            fds[1].events |= libc::POLLOUT;
        }
        link::wait(&mut fds, timeout_ns)?;
        Ok(fds.map(|f| f.revents != 0))
    }

    /// The end of a turn: stderr passed on, STOP published here on SIGTERM or when the near side
    /// has gone (the process is stopped 3 s later if it does not exit), the process's exit.
    /// Some: its exit code.
    fn ended(
        &mut self,
        control: &ipc::ControlOut,
        err_in: bool,
        term: &AtomicBool,
    ) -> Result<Option<u8>> {
        let now = rt::now_ns();
        if err_in {
            self.stderr()?;
        }
        if term.load(Ordering::Relaxed) || self.tcp.closed {
            if !self.stop_sent {
                self.stop_sent = true;
                let stop = ControlMsg::new(ControlKind::Stop, Sender::Supervisor);
                control.send_copy(stop).ipc("publish STOP")?;
            }
            if self.tcp.closed {
                let gone = *self.near_gone_ns.get_or_insert(now);
                if now > gone + 3_000_000_000 {
                    // SAFETY: signalling our own child, not yet reaped.
                    unsafe { libc::kill(self.child.child.id() as i32, libc::SIGTERM) };
                }
            }
        }
        if !(err_in || now > self.next_check) {
            return Ok(None);
        }
        self.next_check = now + 50_000_000;
        let Some(st) = self.child.child.try_wait()? else {
            return Ok(None);
        };
        self.stderr()?;
        use std::os::unix::process::ExitStatusExt;
        Ok(Some(match (st.code(), st.signal()) {
            (Some(c), _) => u8::try_from(c).unwrap_or(EXIT_FAULT),
            (None, Some(sig)) => {
                self.child.last_line =
                    format!("the {} was killed by signal {sig}", self.child.what);
                EXIT_FAULT
            }
            _ => EXIT_FAULT,
        }))
    }

    /// The process's stderr: shown here and sent to the near side line by line.
    fn stderr(&mut self) -> Result<()> {
        let c = &mut self.child;
        let Some(err) = c.child.stderr.as_mut() else {
            return Ok(());
        };
        let mut buf = [0u8; 4096];
        loop {
            match err.read(&mut buf) {
                Ok(0) => break,
                Ok(n) => c.stderr_buf.extend_from_slice(&buf[..n]),
                Err(e) if e.kind() == ErrorKind::WouldBlock => break,
                Err(e) if e.kind() == ErrorKind::Interrupted => {}
                Err(_) => break,
            }
        }
        while let Some(i) = c.stderr_buf.iter().position(|&b| b == b'\n') {
            let line: Vec<u8> = c.stderr_buf.drain(..=i).collect();
            let line = wire::escape_peer_text(&String::from_utf8_lossy(&line[..i]));
            eprintln!("{line}");
            self.tcp.send(Kind::Log, &[line.as_bytes()])?;
            c.last_line = line;
        }
        Ok(())
    }

    /// Tells the near side what this side refused on the link (for the run's record there, and
    /// a warning here) and how the process ended, and waits (a little) for everything queued to
    /// go out. Returns the process's last line on stderr (empty: none), which went with its end.
    fn report(&mut self, code: u8) -> Result<String> {
        if self.direct
            && let Some(h) = &self.handoff
            && let Some(c) = crate::direct::read_counts(h)
        {
            self.udp.absorb(c);
        }
        let refused = crate::seal::SideRefusals {
            refused_datagrams: self.udp.refused.into(),
            icmp_errors: self.udp.icmp_errors,
        };
        self.tcp.send(Kind::Refused, &[&refused.to_wire()])?;
        if let Some(line) = crate::near::refused_warning(&self.udp) {
            eprintln!("{line}");
        }
        let line = self.child.last_line.clone();
        self.tcp.send(
            Kind::Exit,
            &[&u32::from(code).to_ne_bytes(), line.as_bytes()],
        )?;
        let t = rt::now_ns() + 500_000_000;
        while self.tcp.pending() > 0 && !self.tcp.closed && rt::now_ns() < t {
            self.tcp.flush()?;
            std::thread::sleep(Duration::from_millis(1));
        }
        Ok(line)
    }

    /// Says, here and in the run's log on the other host, at START, which path the process took:
    /// the link's socket (its datagrams go to and from it directly), or this side's relay.
    fn say_path(&mut self) -> Result<()> {
        let what = self.child.what;
        let line = if self.direct {
            format!(
                "the {what} here took the link's socket: state and torque go socket to socket (the direct path)"
            )
        } else {
            format!("this side relays the {what} here (the relay path)")
        };
        eprintln!("deltaloop-bridge: {line}");
        self.tcp
            .send(Kind::Log, &[format!("far side: {line}").as_bytes()])
    }

    /// A START or STOP from the near side, published here (START's deadline made absolute on
    /// this host's clock). Returns whether it was START.
    fn run_control(control: &ipc::ControlOut, p: &[u8], hand: &mut Hand<'_>) -> Result<bool> {
        let Some(mut c) = bytes::read::<ControlMsg>(p) else {
            return Ok(false);
        };
        match c.kind() {
            Some(ControlKind::Start) => {
                // The process takes the link's socket before it sees START.
                if let Some(h) = hand.handoff
                    && !*hand.direct
                {
                    *hand.direct =
                        crate::direct::offer(h, hand.udp, hand.session, End::Far, hand.relay)?;
                }
                if *hand.direct {
                    crate::keep_off(hand.loop_cpu);
                }

                c.t0_ns = crate::near::absolute_t0(c.t0_ns);
                control.send_copy(c).ipc("publish START")?;
                Ok(true)
            }
            Some(ControlKind::Stop) => {
                control.send_copy(c).ipc("publish STOP")?;
                Ok(false)
            }
            _ => Ok(false),
        }
    }
}

/// What START needs to hand the link's socket on: the hand-off, the socket, the session, whether
/// the run asks for the relay, and where to say the process took it.
struct Hand<'a> {
    handoff: Option<&'a deltaloop_transport::handoff::End>,
    udp: &'a mut Udp,
    session: &'a Session,
    relay: bool,
    direct: &'a mut bool,
    loop_cpu: Option<usize>,
}

impl FarLink {
    /// The parts of this link START needs ([`Hand`]), beside its TCP stream.
    fn hand(&mut self) -> (&mut Tcp, Hand<'_>) {
        (
            &mut self.tcp,
            Hand {
                handoff: self.handoff.as_ref(),
                udp: &mut self.udp,
                session: &self.session,
                relay: self.relay,
                direct: &mut self.direct,
                loop_cpu: self.loop_cpu,
            },
        )
    }
}

/// `--role controller`: the supervisor and the plant on the controller's host.
struct Far {
    ports: Ports,
    host: ControllerHost,
    /// The READY text of `--controller-cmd`'s label, for a controller that does not name itself
    /// (see [`ready_naming`]).
    named: Option<[u8; 160]>,
}

impl Far {
    /// Carries the run until the controller exits; its exit code.
    fn forward(&mut self, l: &mut FarLink, term: &AtomicBool) -> Result<u8> {
        loop {
            let now = rt::now_ns();
            let timeout = if l.direct {
                crate::near::DIRECT_TURN_NS
            } else {
                self.host.timeout_ns(&l.udp, now)
            };
            let [udp_in, tcp_in, torque_in, err_in] = l.wait(&self.ports.torque_ready, timeout)?;
            let c = &self.ports;
            if l.direct {
                // The replies went to the plant from the controller's socket: a copy of each
                // goes over TCP for the record there, if the plant there took its socket too
                // (else that side's bridge relays, and files, them).
                match &mut self.host.copies {
                    Some(copies) => copies.take(&c.torque, &mut l.tcp)?,
                    None => while c.torque.receive().ipc("receive torque")?.is_some() {},
                }
            } else {
                let ports = (&c.state, &c.torque, &c.state_ready, &c.torque_ready);
                self.host
                    .turn(&ports, (torque_in, udp_in), &mut l.udp, &mut l.tcp)?;
            }
            self.control_plane(l, tcp_in)?;
            if let Some(code) = l.ended(&self.ports.control, err_in, term)? {
                return Ok(code);
            }
        }
    }

    fn control_plane(&mut self, l: &mut FarLink, tcp_in: bool) -> Result<()> {
        while let Some(mut c) = self.ports.control_in.receive().ipc("receive control")? {
            if let Some(text) = self.named
                && c.kind() == Some(ControlKind::Ready)
                && c.text[0] == 0
            {
                c.text = text;
            }
            if c.kind().is_some_and(ControlKind::said_by_controller) {
                l.tcp.send(Kind::Control, &[bytes_of(&c)])?;
            }
        }
        // A recall held for want of room goes out once the connection has taken the last.
        self.host.answer_recalls(&mut l.tcp)?;
        if l.tcp.pending() > 0 {
            l.tcp.flush()?;
        }
        if !tcp_in {
            return Ok(());
        }
        let (ports, host) = (&self.ports, &mut self.host);
        let (mut started, mut finals) = (false, None);
        let (tcp, mut hand) = l.hand();
        tcp.poll(|kind, p| {
            match kind {
                Kind::Recall => host.recall(p),
                Kind::Control => started |= FarLink::run_control(&ports.control, p, &mut hand)?,
                Kind::Reference => {
                    let rows = p.len() / size_of::<RefSample>();
                    ports.reference.send_chunk(rows, &mut |i| {
                        bytes::read::<RefSample>(
                            &p[i * size_of::<RefSample>()..(i + 1) * size_of::<RefSample>()],
                        )
                        .unwrap_or_default()
                    })?;
                }
                Kind::Final => finals = bytes::read::<StateMsg>(p),
                // The plant there took its socket: the record there needs a copy of each reply
                // (when this side relays; on the direct path it sends them anyway).
                Kind::NearDirect => {
                    host.copies.get_or_insert_with(Default::default);
                }
                _ => {}
            }
            Ok(())
        })?;
        if started {
            l.say_path()?;
        }
        self.host.answer_recalls(&mut l.tcp)?;
        let ports = (&self.ports.state, &self.ports.state_ready);
        if started {
            self.host.start(ports)?;
        }
        if let Some(s) = finals {
            self.host.publish_state(ports, s)?;
        }
        Ok(())
    }
}

/// `--role plant`: the supervisor and the controller on the plant's host.
struct FarPlant {
    ports: PlantSidePorts,
    host: PlantHost,
}

impl FarPlant {
    /// Carries the run until the plant exits; its exit code.
    fn forward(&mut self, l: &mut FarLink, term: &AtomicBool) -> Result<u8> {
        loop {
            let timeout = if l.direct {
                crate::near::DIRECT_TURN_NS
            } else {
                self.host.timeout_ns(&l.udp, rt::now_ns())
            };
            let [udp_in, tcp_in, state_in, err_in] = l.wait(&self.ports.state_ready, timeout)?;
            // Run control first: a STOP must reach the plant before anything it answers.
            self.control_plane(l, tcp_in)?;
            self.host.direct = l.direct;
            let c = &self.ports;
            let ports = (&c.state, &c.torque, &c.state_ready, &c.torque_ready);
            let ready = (state_in, udp_in);
            self.host.turn(&ports, ready, &mut l.udp, &mut l.tcp)?;
            self.plant_out(l)?;
            if let Some(code) = l.ended(&self.ports.control, err_in, term)? {
                // What the plant published last (its final state, the safe stop's telemetry)
                // goes out before its end.
                self.plant_out(l)?;
                let ports = (&self.ports.state, &self.ports.state_ready);
                self.host.states(ports, &mut l.udp, &mut l.tcp)?;
                return Ok(code);
            }
        }
    }

    /// The near side's run control and the controller's READY/ARMED in.
    fn control_plane(&mut self, l: &mut FarLink, tcp_in: bool) -> Result<()> {
        if !tcp_in {
            return Ok(());
        }
        let ports = &self.ports;
        let mut started = false;
        let (tcp, mut hand) = l.hand();
        tcp.poll(|kind, p| {
            if kind == Kind::Control {
                started |= FarLink::run_control(&ports.control, p, &mut hand)?;
                crate::sides::say_as_controller(p, &ports.as_controller, &ports.torque_ready)?;
            }
            Ok(())
        })?;
        if started {
            l.say_path()?;
        }
        Ok(())
    }

    /// The plant's control messages and telemetry out over TCP (reliable, in order).
    fn plant_out(&mut self, l: &mut FarLink) -> Result<()> {
        while let Some(s) = self
            .ports
            .control_in
            .receive()
            .ipc("receive plant control")?
        {
            l.tcp.send(Kind::Control, &[bytes_of(&s)])?;
        }
        while let Some(s) = self.ports.telemetry.receive().ipc("receive telemetry")? {
            l.tcp.queue(Kind::Telemetry, &[bytes_of(&s)])?;
        }
        if l.tcp.pending() > 0 {
            l.tcp.flush()?;
        }
        Ok(())
    }
}

/// Relays the run between the local process's ports and the link until it ends, then reports
/// its end to the near side ([`FarLink::report`], the ports closed): the process's exit code and
/// its last line on stderr (empty: none). `(spin_ns, mode, far_emu)`: how this side polls, the
/// loop mode, and its emulated link. `named`: the READY text naming a controller of the user's
/// ([`ready_naming`]).
pub(super) fn relay(
    ports: Either,
    link: &mut FarLink,
    (spin_ns, mode, far_emu): (u64, LoopMode, crate::emulation::Emulation),
    named: Option<[u8; 160]>,
    term: &AtomicBool,
) -> Result<(u8, String)> {
    let code = match ports {
        Either::Controller(ports) => {
            let mut f = Far {
                ports,
                host: ControllerHost::new(spin_ns, false),
                named,
            };
            let code = f.forward(link, term)?;
            if f.host.stale > 0 {
                eprintln!(
                    "deltaloop-bridge: {} state(s) of a backlog not passed on to the controller (a newer one went instead)",
                    f.host.stale
                );
            }
            if f.host.refused_recalls() > 0 {
                eprintln!(
                    "deltaloop-bridge: warning: refused {} recall(s) of replies from the near side (malformed, beyond the ring, or too many at once)",
                    f.host.refused_recalls()
                );
            }
            code
        }
        Either::Plant(ports) => {
            let mut f = FarPlant {
                ports,
                host: PlantHost::new(spin_ns, mode == LoopMode::Lockstep).with_record(),
            };
            let code = f.forward(link, term)?;
            let counts = f.host.counts();
            crate::near::link_summary(&far_emu, link.emulated_lost(), Some(counts));
            code
        }
    };
    let last = link.report(code)?;
    Ok((code, last))
}

pub(super) fn spawn(
    cmd: &[String],
    run_id: &str,
    mode: LoopMode,
    config: &std::path::Path,
    law: Option<&str>,
    handoff: &deltaloop_transport::handoff::End,
) -> Result<FarChild> {
    let what = if law.is_some() { "controller" } else { "plant" };
    let mut c = Command::new(&cmd[0]);
    c.args(&cmd[1..])
        .args(["--run-id", run_id, "--config"])
        .arg(config)
        .args(["--mode", mode.name()])
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::piped());
    if let Some(law) = law {
        c.args(["--law", law]);
    }
    // The link key is this bridge's, never the process's it starts.
    crate::seal::scrub_secrets(&mut c);
    rt::die_with_parent(&mut c);
    // The process may take the link's socket at START (the direct path).
    deltaloop_transport::handoff::inherit(&mut c, handoff);
    let child = c
        .spawn()
        .with_context(|| format!("cannot start the {what} `{}`", cmd.join(" ")))?;
    if let Some(e) = &child.stderr {
        use std::os::fd::AsRawFd;
        // SAFETY: setting O_NONBLOCK on a pipe descriptor we own.
        unsafe {
            let fl = libc::fcntl(e.as_raw_fd(), libc::F_GETFL);
            libc::fcntl(e.as_raw_fd(), libc::F_SETFL, fl | libc::O_NONBLOCK);
        }
    }
    Ok(FarChild {
        child,
        what,
        stderr_buf: Vec::with_capacity(4096),
        last_line: String::new(),
    })
}

/// The process this side started, its stderr and its end.
pub(super) struct FarChild {
    child: Child,
    /// `controller` or `plant`.
    what: &'static str,
    stderr_buf: Vec<u8>,
    last_line: String,
}

impl Drop for FarChild {
    fn drop(&mut self) {
        if self.child.try_wait().ok().flatten().is_none() {
            // SAFETY: signalling our own child, not yet reaped.
            unsafe { libc::kill(self.child.id() as i32, libc::SIGTERM) };
            for _ in 0..200 {
                if self.child.try_wait().ok().flatten().is_some() {
                    return;
                }
                std::thread::sleep(Duration::from_millis(5));
            }
            let _ = self.child.kill();
            let _ = self.child.wait();
        }
    }
}
