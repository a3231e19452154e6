//! The near side standing in for a remote plant: states from the link, replies to it.

use super::*;

/// `--role plant`: the plant's stand-in on the controller's (and the supervisor's) host.
struct NearPlant {
    ports: PlantPorts,
    peer: Peer,
    host: ControllerHost,
    /// The link is taken for lost after this long without a word from the far side while the
    /// loop runs and the controller here owes no reply, ns.
    silence_ns: u64,
    /// When START went to the far side.
    started_ns: Option<u64>,
    /// When the far side was last heard (a datagram or a frame), or a reply last went to it.
    heard_ns: u64,
    /// The states' copies that came over TCP (arrival, state), oldest first, each waiting for
    /// its datagram: a copy whose datagram has not come within `hold_ns` (lost on the link), or
    /// that a newer state has overtaken, is published itself, so the supervisor here records
    /// every state. Pre-allocated ([`COPIES`]).
    copies: VecDeque<(u64, StateMsg)>,
    /// When the final state was published here (the far plant's, or ours on giving up).
    final_ns: Option<u64>,
    /// How long a copy waits for its datagram: the emulated delay and jitter, and 1 ms.
    hold_ns: u64,
}

/// States' copies held at most; a fuller queue publishes its oldest.
const COPIES: usize = 1024;

/// Stands in for the plant across the link until the run ends (`silence_ms` the run's controller
/// silence timeout, `hold_ns` how long a state's copy waits for its datagram), then hands the
/// link's peer and how the run ended to `end`, the run's end, while the ports here are still open.
pub(super) fn stand_in<R>(
    (ports, peer): (PlantPorts, Peer),
    (spin_ns, silence_ms, hold_ns): (u64, u64, u64),
    term: &AtomicBool,
    end: impl FnOnce(&mut Peer, Result<(u8, Option<String>)>) -> R,
) -> R {
    let mut n = NearPlant::new(ports, peer, spin_ns, silence_ms, hold_ns);
    let r = n.forward(term);
    end(&mut n.peer, r)
}

impl NearPlant {
    /// The stand-in for a plant across the link, `silence_ms` the run's controller silence
    /// timeout and `hold_ns` how long a state's copy waits for its datagram.
    fn new(ports: PlantPorts, peer: Peer, spin_ns: u64, silence_ms: u64, hold_ns: u64) -> Self {
        Self {
            ports,
            peer,
            host: ControllerHost::new(spin_ns, true),
            // Half the silence timeout: before the controller's own silence rule ends it.
            silence_ns: (silence_ms * 1_000_000 / 2).max(100_000_000),
            started_ns: None,
            heard_ns: 0,
            copies: VecDeque::with_capacity(COPIES),
            final_ns: None,
            hold_ns,
        }
    }

    fn forward(&mut self, term: &AtomicBool) -> Result<(u8, Option<String>)> {
        loop {
            let now = rt::now_ns();
            let timeout = if self.peer.direct {
                DIRECT_TURN_NS
            } else {
                self.host.timeout_ns(&self.peer.udp, now)
            };
            let [udp_in, tcp_in, torque_in] = self.peer.wait(&self.ports.torque_ready, timeout)?;
            let c = &self.ports;
            let ports = (&c.state, &c.torque, &c.state_ready, &c.torque_ready);
            // On the direct path the loop's messages do not pass here: the states arrive as
            // the record's copies over TCP, and the controller's replies go to the plant.
            if !self.peer.direct
                && self.host.turn(
                    &ports,
                    (torque_in, udp_in),
                    &mut self.peer.udp,
                    &mut self.peer.tcp,
                )?
            {
                self.heard_ns = rt::now_ns();
            }
            self.control_plane(tcp_in)?;
            self.settle_copies()?;
            if let Some(end) = self.peer.ended(term)? {
                return Ok(end);
            }
            let now = rt::now_ns();
            if let Some(end) = self.peer.stop_overdue(now) {
                // Nothing more will come: release the controller here, as the plant would.
                self.release()?;
                return Ok(end);
            }
            if let Some(t) = self.final_ns {
                if now > t + FAR_END_WAIT_NS {
                    eprintln!(
                        "deltaloop-bridge: warning: the far side did not report its end within {} ms of the final state (the link is down?)",
                        FAR_END_WAIT_NS / 1_000_000
                    );
                    return Ok((0, None));
                }
                continue;
            }
            if !self.peer.direct && self.host.awaiting_reply() {
                self.heard_ns = now;
            }
            if self.started_ns.is_some() && now > self.heard_ns + self.silence_ns {
                return self.link_lost();
            }
        }
    }

    /// The supervisor's run control and the controller's READY/ARMED out; the far plant's
    /// control, telemetry, final state, log and end in.
    fn control_plane(&mut self, tcp_in: bool) -> Result<()> {
        let p = &mut self.peer;
        if p.forward_control(&self.ports.control)? && self.started_ns.is_none() {
            // START is out (the controller here has it too): from now on the far side must be
            // heard, and its states go to the controller.
            let now = rt::now_ns();
            self.started_ns = Some(now);
            self.heard_ns = now;
            self.host.quiet = p.direct;
            self.host
                .start((&self.ports.state, &self.ports.state_ready))?;
        }
        while let Some(c) = self
            .ports
            .from_controller
            .receive()
            .ipc("receive control")?
        {
            if c.kind().is_some_and(ControlKind::said_by_controller) {
                p.tcp.send(Kind::Control, &[bytes_of(&c)])?;
            }
        }
        if p.tcp.pending() > 0 {
            p.tcp.flush()?;
        }
        if !tcp_in && !p.tcp.held() {
            return Ok(());
        }
        let (ports, far_end, copies, log) =
            (&self.ports, &mut p.far_end, &mut self.copies, &mut p.log);
        let far_refused = &mut p.report.far;
        let host = &mut self.host;
        let (mut heard, mut finals) = (false, None);
        let now = rt::now_ns();
        p.tcp.poll(|kind, b| {
            heard = true;
            match kind {
                Kind::State => {
                    if let Some(s) = bytes::read::<StateMsg>(b) {
                        if copies.len() == COPIES
                            && let Some((_, old)) = copies.pop_front()
                            && host.started
                            && !host.published(old.tick)
                        {
                            // Its datagram is long due: published now, each one (regression:
                            // only the last copy evicted in one poll was, the others were lost
                            // to the record).
                            host.publish_state((&ports.state, &ports.state_ready), old)?;
                        }
                        copies.push_back((now, s));
                    }
                }
                Kind::Control => {
                    // Only what a plant may say, as the plant (this process is its stand-in).
                    if let Some(mut c) = bytes::read::<ControlMsg>(b)
                        && c.kind().is_some_and(ControlKind::said_by_plant)
                    {
                        c.from = Sender::Plant as u32;
                        ports.control.0.send_copy(c).ipc("send plant control")?;
                    }
                }
                Kind::Telemetry => {
                    if let Some(t) = bytes::read::<TelemetryMsg>(b) {
                        ports.telemetry.send_copy(t).ipc("publish telemetry")?;
                    }
                }
                Kind::Final => finals = bytes::read::<StateMsg>(b),
                Kind::Log => log.line(b),
                Kind::Refused => *far_refused = far_refusals(b),
                Kind::Exit => *far_end = Some(FarEnd::of(b)),
                _ => {}
            }
            Ok(())
        })?;
        if heard {
            self.heard_ns = rt::now_ns();
        }
        if let Some(s) = finals {
            self.settle_copies_until(u64::MAX)?;
            self.host
                .publish_state((&self.ports.state, &self.ports.state_ready), s)?;
            self.final_ns.get_or_insert(rt::now_ns());
        }
        Ok(())
    }

    /// Publishes the states' copies whose datagram is lost (see `copies`); drops the others.
    fn settle_copies(&mut self) -> Result<()> {
        self.settle_copies_until(rt::now_ns().saturating_sub(self.hold_ns))
    }

    /// [`Self::settle_copies`], taking a copy that arrived before `due` (ns) for lost.
    fn settle_copies_until(&mut self, due: u64) -> Result<()> {
        let ports = (&self.ports.state, &self.ports.state_ready);
        while let Some(&(at, s)) = self.copies.front() {
            if self.host.published(s.tick) {
                self.copies.pop_front();
                continue;
            }
            let overtaken = self.host.newest().is_some_and(|n| n > s.tick);
            if !(overtaken || at < due) || !self.host.started {
                break;
            }
            self.host.publish_state(ports, s)?;
            self.copies.pop_front();
        }
        Ok(())
    }

    /// The far side went silent while the loop ran: the far plant's own rules stop it there
    /// (it brakes to a safe stop). Releases the controller here with a final state (as the plant
    /// would) and ends with a fault saying what is known.
    fn link_lost(&mut self) -> Result<(u8, Option<String>)> {
        let last = self.host.last_state;
        self.release()?;
        let after = last.map_or("before tick 0".into(), |s| format!("after tick {}", s.tick));
        Ok((
            EXIT_FAULT,
            Some(format!(
                "the link to the plant's host went silent {after} (no word for {} ms): the far plant's own rules (controller silence) brake it to a safe stop there, not on record here",
                self.silence_ns / 1_000_000
            )),
        ))
    }
}

impl NearPlant {
    /// Releases the controller here with a final state (the last one again), as the plant
    /// would at its end, unless the final state came.
    fn release(&mut self) -> Result<()> {
        if self.final_ns.is_some() {
            return Ok(());
        }
        if let Some(mut s) = self.host.last_state {
            s.flags |= wire::STATE_FINAL;
            let ports = (&self.ports.state, &self.ports.state_ready);
            self.host.publish_state(ports, s)?;
        }
        self.final_ns = Some(rt::now_ns());
        Ok(())
    }
}
