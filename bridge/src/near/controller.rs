//! The near side standing in for a remote controller: states to the link, replies from it.

use super::*;

/// `--role controller`: the controller's stand-in on the plant's host.
pub(super) struct Near {
    pub(super) ports: Ports,
    pub(super) peer: Peer,
    pub(super) host: PlantHost,
    /// Reply copies that came too late for the record ([`crate::sides::RECORD_HORIZON`]).
    pub(super) late_copies: u64,
}

impl Near {
    pub(super) fn forward(&mut self, term: &AtomicBool) -> Result<(u8, Option<String>)> {
        loop {
            let timeout = if self.peer.direct {
                DIRECT_TURN_NS
            } else {
                self.host.timeout_ns(&self.peer.udp, rt::now_ns())
            };
            let [udp_in, tcp_in, state_in] = self.peer.wait(&self.ports.state_ready, timeout)?;
            self.peer.forward_control(&self.ports.control)?;
            self.host.direct = self.peer.direct;
            let (p, c) = (&mut self.peer, &self.ports);
            let ports = (&c.state, &c.torque, &c.state_ready, &c.torque_ready);
            let ready = (state_in, udp_in);
            self.host.turn(&ports, ready, &mut p.udp, &mut p.tcp)?;
            self.host.recall_out(&mut p.tcp)?;
            self.control_plane(tcp_in)?;
            if let Some(end) = self.peer.ended(term)? {
                self.give_up(true)?;
                return Ok(end);
            }
            self.give_up(false)?;
            let now = rt::now_ns();
            if let Some(end) = self.peer.stop_overdue(now) {
                self.give_up(true)?;
                return Ok(end);
            }
            if self
                .host
                .final_sent_ns
                .is_some_and(|t| now > t + FAR_END_WAIT_NS)
            {
                self.give_up(true)?;
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

    /// The reference out, the far side's control, log and end in.
    fn control_plane(&mut self, tcp_in: bool) -> Result<()> {
        let p = &mut self.peer;
        // One chunk at a time in flight: the subscriber keeps the rest (REF_RING deep).
        while p.tcp.pending() < 64 * 1024 {
            let Some(chunk) = self.ports.reference.receive().ipc("receive reference")? else {
                break;
            };
            p.tcp
                .send(Kind::Reference, &[bytes_of_slice(chunk.payload())])?;
        }
        if p.tcp.pending() > 0 {
            p.tcp.flush()?;
        }
        if !tcp_in && !p.tcp.held() {
            return Ok(());
        }
        let (ports, far_end, log) = (&self.ports, &mut p.far_end, &mut p.log);
        let (far_refused, host) = (&mut p.report.far, &mut self.host);
        let (newest, late) = (host.newest_state, &mut self.late_copies);
        p.tcp.poll(|kind, p| {
            match kind {
                Kind::Replies => *late += crate::sides::file_replies(p, &ports.torque, newest)?,
                Kind::Recalled => {
                    let mut said = Ok(());
                    let torque = (&ports.torque, &ports.torque_ready);
                    host.recalled(p, torque, |first, last| {
                        if said.is_ok() {
                            said = replies_lost(&ports.control.0, first, last);
                        }
                    })?;
                    said?;
                }
                // This process is the controller's stand-in.
                Kind::Control => {
                    crate::sides::say_as_controller(p, &ports.control.0, &ports.torque_ready)?
                }
                Kind::Log => log.line(p),
                Kind::Refused => *far_refused = far_refusals(p),
                Kind::Exit => *far_end = Some(FarEnd::of(p)),
                _ => {}
            }
            Ok(())
        })
    }
}

impl Near {
    /// Tells the supervisor, as the controller, the ticks of the holes that will not be
    /// recovered: those whose recall is overdue, or all of them (`all`: the link is gone).
    fn give_up(&mut self, all: bool) -> Result<()> {
        if !self.host.recalls.busy() {
            return Ok(());
        }
        let mut said = Ok(());
        let control = &self.ports.control.0;
        self.host.recalls.give_up(rt::now_ns(), all, |first, last| {
            if said.is_ok() {
                said = replies_lost(control, first, last);
            }
        });
        said
    }
}

/// REPLIES_LOST, as the controller: its replies to ticks `first..=last` may have been lost on
/// the link, and could not be recovered.
fn replies_lost(control: &ipc::ControlOut, first: u64, last: u64) -> Result<()> {
    let mut m = ControlMsg::with_text(
        ControlKind::RepliesLost,
        Sender::Controller,
        first,
        "replies lost on the link between the hosts and not recovered",
    );
    m.ticks = last;
    control.send_copy(m).ipc("send REPLIES_LOST")?;
    Ok(())
}
