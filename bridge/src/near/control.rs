//! Run control across the link, for both roles: one turn's wait, the supervisor's START and
//! STOP to the far side, and the far side's end.

use super::*;

/// A bridge's turn on the direct path, when nothing wakes it, ns: the pace of the record's
/// copies and of run control (the loop's messages do not pass here).
pub const DIRECT_TURN_NS: u64 = 1_000_000;

/// How long the far side has to report its end after the final state or a STOP, ns: the
/// supervisor gives a controller 1 s after the plant exits.
pub(super) const FAR_END_WAIT_NS: u64 = 700_000_000;

impl Peer {
    /// The wait of one turn: the socket, the control connection and the wake-up `event`.
    pub(super) fn wait(&self, event: &ipc::Wake, timeout_ns: u64) -> Result<[bool; 3]> {
        let mut fds = [
            link::readable(&self.udp.sock),
            link::readable(&self.tcp.stream),
            link::event(event),
        ];
        if self.direct {
            // The socket is the loop process's now (ppoll skips a negative descriptor).
            fds[0].fd = -1;
        }
        if self.tcp.pending() > 0 {
            fds[1].events |= libc::POLLOUT;
        }
        link::wait(&mut fds, timeout_ns)?;
        Ok(fds.map(|f| f.revents != 0))
    }

    /// The supervisor's run control out (START with its deadline made relative, STOP). Before
    /// the states of each wake-up: a STOP must reach the far side before the final state it
    /// causes. Returns whether START went out.
    pub(super) fn forward_control(&mut self, control: &ControlPorts) -> Result<bool> {
        let mut started = false;
        while let Some(mut c) = control.1.receive().ipc("receive control")? {
            match (c.kind(), c.sender()) {
                (Some(ControlKind::Start), Some(Sender::Supervisor)) => {
                    if let Some(h) = &self.handoff {
                        self.direct = crate::direct::offer(
                            h,
                            &mut self.udp,
                            &self.session,
                            End::Near,
                            self.relay,
                        )?;
                        if self.direct && self.role == RemoteSide::Controller {
                            self.tcp.send(Kind::NearDirect, &[])?;
                        }
                        if self.direct {
                            crate::keep_off(self.loop_cpu);
                        }
                        let here = match self.role {
                            RemoteSide::Controller => "plant",
                            RemoteSide::Plant => "controller",
                        };
                        eprintln!(
                            "deltaloop-bridge: {}",
                            if self.direct {
                                format!(
                                    "the {here} here took the link's socket: state and torque go socket to socket (the direct path)"
                                )
                            } else {
                                format!("this side relays the {here} here (the relay path)")
                            }
                        );
                    }
                    c.t0_ns = c.t0_ns.saturating_sub(rt::now_ns());
                    self.tcp.send(Kind::Control, &[bytes_of(&c)])?;
                    started = true;
                }
                (Some(ControlKind::Stop), Some(Sender::Supervisor)) => {
                    self.tcp.send(Kind::Control, &[bytes_of(&c)])?;
                    self.stop_sent_ns.get_or_insert(rt::now_ns());
                }
                _ => {}
            }
        }
        Ok(started)
    }

    /// The end of a turn, for both roles: the far side's end, a closed link, a SIGTERM (STOP to
    /// the far side). Some: the near side exits with it.
    pub(super) fn ended(&mut self, term: &AtomicBool) -> Result<Option<(u8, Option<String>)>> {
        if let Some(end) = self.far_end.take() {
            return Ok(Some(end.exit()));
        }
        if self.tcp.closed {
            return Ok(Some((
                EXIT_FAULT,
                Some(
                    "the link's control connection closed before the far side reported its end"
                        .into(),
                ),
            )));
        }
        if term.load(Ordering::Relaxed) && self.stop_sent_ns.is_none() {
            let stop = ControlMsg::new(ControlKind::Stop, Sender::Supervisor);
            self.tcp.send(Kind::Control, &[bytes_of(&stop)])?;
            self.stop_sent_ns = Some(rt::now_ns());
        }
        Ok(None)
    }

    /// A STOP (the supervisor's, or SIGTERM's) went out [`FAR_END_WAIT_NS`] ago and the far side
    /// has not reported its end: the near side gives up waiting (the link is down?).
    pub(super) fn stop_overdue(&self, now: u64) -> Option<(u8, Option<String>)> {
        self.stop_sent_ns
            .is_some_and(|t| now > t + FAR_END_WAIT_NS)
            .then(|| {
                (
                    EXIT_STOPPED,
                    Some(format!(
                        "stopped; the far side did not report its end within {} ms (the link is down?)",
                        FAR_END_WAIT_NS / 1_000_000
                    )),
                )
            })
    }
}
