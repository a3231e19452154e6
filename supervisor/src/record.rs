//! What a run leaves behind: one [`TickRecord`] per control tick, the state after the last tick,
//! and how the run ended. Every loop mode feeds the same [`Recorder`] the same three message
//! streams (state, reply, telemetry, tick by tick and in order), so a row of `trace.csv`, the
//! divergence rule and every metric come from one place whatever the transport.

use deltaloop_config::Law;
use deltaloop_law::Output;
use deltaloop_model::{PlantSample, Vec3};
use deltaloop_transport::wire::{self, StateMsg, TelemetryMsg, TorqueMsg};

/// Error bound of the divergence rule, rad (docs/controllers.md: |e_i| > 0.5 rad).
pub const DIVERGENCE_ERR_RAD: f64 = 0.5;

/// What became of the controller's reply to tick k (`trace.csv` column `reply`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ReplyFate {
    /// It arrived in time and went to the drives (which may still clamp or reject it).
    Applied,
    /// The controller answered after the torque budget: dropped, the drives held.
    Late,
    /// The controller never answered this state: it answered a newer one instead.
    Skipped,
    /// No answer at all: the drives held.
    Missed,
}

impl ReplyFate {
    /// The `trace.csv` word.
    pub fn name(self) -> &'static str {
        match self {
            ReplyFate::Applied => "applied",
            ReplyFate::Late => "late",
            ReplyFate::Skipped => "skipped",
            ReplyFate::Missed => "missed",
        }
    }
}

/// One control tick.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TickRecord {
    /// The plant sample the controller saw (tick k, q, q̇, τᵃ_k).
    pub sample: PlantSample,
    /// The plant's true (noise-free) joint rates q̇_k, rad/s: the TDE ground truth.
    pub qd_true: Vec3,
    /// The true joint angles q_k, rad.
    pub q_true: Vec3,
    /// The controller's answer to tick k; None if it never produced one.
    pub out: Option<Output>,
    /// The torque the torque metrics count for tick k, N m: the command τ_k, or, with no reply,
    /// the torque the drives held over [t_k, t_{k+1}) (τᵃ_{k+1}).
    pub tau: Vec3,
    /// What became of the reply.
    pub fate: ReplyFate,
    /// Some joint was clamped over [t_k, t_{k+1}).
    pub clamped: bool,
    /// The plant held the previous torque over [t_k, t_{k+1}) (missed or rejected command).
    pub held: bool,
    /// The plant rejected the command (non-finite, or over the limit under `reject`).
    pub rejected: bool,
}

/// The measured part of a state message: tick k, q, q̇ and τᵃ_k as the controller saw them.
fn measured(s: &StateMsg) -> PlantSample {
    PlantSample {
        k: s.tick,
        q: Vec3::from(s.q),
        qd: Vec3::from(s.qd),
        tau_applied: Vec3::from(s.tau_applied),
    }
}

impl LawRun {
    /// What the truth N_k of record `i` needs from tick k + 1: (q̇_{k+1} true, τᵃ_{k+1}); None
    /// if tick k + 1 was not seen.
    pub fn next_of(&self, i: usize) -> Option<(Vec3, Vec3)> {
        let k = self.records[i].sample.k;
        match self.records.get(i + 1) {
            Some(r) if r.sample.k == k + 1 => Some((r.qd_true, r.sample.tau_applied)),
            Some(_) => None,
            None => self
                .after
                .filter(|(s, _)| s.k == k + 1)
                .map(|(s, qd)| (qd, s.tau_applied)),
        }
    }
}

/// A loop fault: the tick it happened at and a one-line cause.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Fault {
    pub tick: u64,
    pub cause: String,
}

/// How a run ended.
#[derive(Clone, Debug, PartialEq)]
pub enum Outcome {
    /// All ticks 0..=N ran.
    Completed,
    /// Stopped at `tick` (error above the bound, a non-finite value, or the robot left its workspace).
    Diverged { tick: u64, reason: String },
    /// Stopped at `tick` by Ctrl-C / SIGTERM; the ticks before it are kept.
    Interrupted { tick: u64 },
    /// Stopped by the loop fault in [`LawRun::fault`] (a process died, stalled, or the plant failed).
    Faulted,
    /// The loop ran to its end, but the supervisor lost ticks of the stream (it fell behind the
    /// loop; its queues overflowed): [`LawRun::lost_ticks`] of them, the first at
    /// [`LawRun::first_lost`]. Every tick it saw is recorded.
    LostData,
}

/// A finished run of one law.
#[derive(Clone, Debug)]
pub struct LawRun {
    pub law: Law,
    /// The recorded ticks, in order: 0..=last but for the lost ones.
    pub records: Vec<TickRecord>,
    /// Ticks the supervisor never saw (its queues overflowed): not in `records`.
    pub lost_ticks: u64,
    /// The first lost tick, if any.
    pub first_lost: Option<u64>,
    /// The plant state after the last recorded tick (tick last + 1), if the plant got there.
    pub after: Option<(PlantSample, Vec3)>,
    pub outcome: Outcome,
    /// A loop fault. Kept even when the divergence rule ended the trace first (e.g. the robot
    /// drifting while the plant held the torque of a dead controller).
    pub fault: Option<Fault>,
}

/// Collects ticks and applies the divergence rule. Pre-allocated for the whole run.
#[derive(Debug)]
pub struct Recorder {
    run: LawRun,
}

impl Recorder {
    /// Room for ticks 0..=n.
    pub fn new(law: Law, n: usize) -> Self {
        Self {
            run: LawRun {
                law,
                records: Vec::with_capacity(n + 1),
                lost_ticks: 0,
                first_lost: None,
                after: None,
                outcome: Outcome::Completed,
                fault: None,
            },
        }
    }

    /// Records tick k: the state the plant published and the controller's reply to it (None: it
    /// never answered this state). Returns false, having marked the run diverged, if the tick
    /// breaks the divergence rule; the caller must stop. Call [`Recorder::applied`] next.
    pub fn tick(&mut self, state: &StateMsg, reply: Option<&TorqueMsg>, q_des: &Vec3) -> bool {
        let sample = measured(state);
        self.hold_previous(sample.k, sample.tau_applied);
        // A reply for tick k says how many older states the controller skipped to reach it.
        if let Some(r) = reply {
            let skipped = usize::try_from(r.skipped).unwrap_or(usize::MAX);
            let oldest = state.tick.saturating_sub(r.skipped);
            for prev in self.run.records.iter_mut().rev().take(skipped) {
                if prev.sample.k >= oldest && prev.fate == ReplyFate::Missed {
                    prev.fate = ReplyFate::Skipped;
                }
            }
        }
        let out = reply.map(|t| Output {
            tau: Vec3::from(t.tau),
            s: Vec3::from(t.s),
            n_hat: Vec3::from(t.n_hat),
            u: Vec3::from(t.u),
        });
        self.run.records.push(TickRecord {
            sample,
            q_true: Vec3::from(state.q_true),
            qd_true: Vec3::from(state.qd_true),
            out,
            tau: out.map_or(sample.tau_applied, |o| o.tau),
            fate: if out.is_some() {
                ReplyFate::Applied
            } else {
                ReplyFate::Missed
            },
            clamped: false,
            held: false,
            rejected: false,
        });
        let e = q_des - sample.q;
        let reason = if !(sample
            .q
            .iter()
            .chain(sample.qd.iter())
            .all(|x| x.is_finite()))
        {
            Some("non-finite joint state".to_string())
        } else if out.is_some_and(|o| !o.tau.iter().all(|x| x.is_finite())) {
            Some("non-finite torque command".to_string())
        } else if e.amax() > DIVERGENCE_ERR_RAD {
            Some(format!(
                "tracking error {:.3} rad exceeds {DIVERGENCE_ERR_RAD} rad",
                e.amax()
            ))
        } else {
            None
        };
        match reason {
            Some(reason) => {
                self.run.outcome = Outcome::Diverged {
                    tick: sample.k,
                    reason,
                };
                false
            }
            None => true,
        }
    }

    /// A tick without a reply counts the torque the drives held over it: τᵃ of the next state
    /// (tick `next`; nothing is patched across a lost tick).
    fn hold_previous(&mut self, next: u64, tau_next: Vec3) {
        if let Some(prev) = self.run.records.last_mut()
            && prev.out.is_none()
            && prev.sample.k + 1 == next
        {
            prev.tau = tau_next;
        }
    }

    /// Tick k never reached the supervisor (its queues overflowed while it was not draining): it
    /// is counted, and has no row.
    pub fn lost(&mut self, k: u64) {
        self.run.lost_ticks += 1;
        self.run.first_lost.get_or_insert(k);
    }

    /// Marks what the plant did over the last recorded tick, from its telemetry (None: not seen).
    pub fn applied(&mut self, tel: Option<&TelemetryMsg>) {
        let flags = tel.map_or(0, |m| m.flags);
        if let Some(r) = self.run.records.last_mut() {
            r.clamped = flags & wire::TEL_CLAMPED != 0;
            r.held = flags & wire::TEL_HELD != 0;
            r.rejected = flags & wire::TEL_REJECTED != 0;
            if r.out.is_some() && flags & wire::TEL_MISSED != 0 {
                r.fate = ReplyFate::Late;
            }
        }
    }

    /// The plant failed while integrating the last recorded tick (e.g. left the workspace).
    pub fn plant_failed(&mut self, reason: String) {
        let tick = self.run.records.last().map_or(0, |r| r.sample.k + 1);
        self.run.outcome = Outcome::Diverged { tick, reason };
    }

    /// The run was interrupted by a signal after the last recorded tick.
    pub fn interrupt(&mut self) {
        let tick = self.run.records.last().map_or(0, |r| r.sample.k + 1);
        self.run.outcome = Outcome::Interrupted { tick };
    }

    /// The loop faulted at `tick`. Unless something later ends the trace otherwise (divergence,
    /// an interrupt), the run ends as [`Outcome::Faulted`]; the fault is kept either way.
    pub fn fault(&mut self, fault: Fault) {
        self.run.fault = Some(fault);
        self.run.outcome = Outcome::Faulted;
    }

    /// Stores the state after the last tick (N + 1, or wherever the plant stopped), if the plant
    /// got there, and returns the run.
    pub fn finish(mut self, after: Option<&StateMsg>) -> LawRun {
        self.run.after = after.map(|s| {
            let sample = measured(s);
            self.hold_previous(sample.k, sample.tau_applied);
            (sample, Vec3::from(s.qd_true))
        });
        if self.run.outcome == Outcome::Completed && self.run.first_lost.is_some() {
            self.run.outcome = Outcome::LostData;
        }
        self.run
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn state(k: u64, q: f64, tau_applied: f64) -> StateMsg {
        StateMsg {
            tick: k,
            q: [q; 3],
            q_true: [q; 3],
            tau_applied: [tau_applied; 3],
            ..StateMsg::default()
        }
    }

    fn reply(k: u64, tau: f64, skipped: u64) -> TorqueMsg {
        TorqueMsg {
            tick: k,
            tau: [tau; 3],
            skipped,
            ..TorqueMsg::default()
        }
    }

    fn tick(rec: &mut Recorder, k: u64, q: f64) -> bool {
        rec.tick(&state(k, q, 0.0), Some(&reply(k, 0.0, 0)), &Vec3::zeros())
    }

    #[test]
    fn a_fault_ends_an_otherwise_healthy_trace() {
        let mut rec = Recorder::new(Law::Tdc, 10);
        let fault = Fault {
            tick: 3,
            cause: "controller died".into(),
        };
        rec.fault(fault.clone());
        assert!(tick(&mut rec, 0, 0.0) && tick(&mut rec, 1, 0.0));
        let run = rec.finish(None);
        assert_eq!(run.outcome, Outcome::Faulted);
        assert_eq!(run.fault, Some(fault));
    }

    /// The robot can drift out of bounds while the plant holds a dead controller's torque: the
    /// run is diverged, and the fault that caused it stays on record (once patched on afterwards).
    #[test]
    fn fault_kept_when_divergence_ends_the_trace_first() {
        let mut rec = Recorder::new(Law::Tdc, 10);
        rec.fault(Fault {
            tick: 5,
            cause: "controller died".into(),
        });
        assert!(tick(&mut rec, 0, 0.0));
        assert!(!tick(&mut rec, 1, 2.0 * DIVERGENCE_ERR_RAD));
        let run = rec.finish(None);
        assert!(matches!(run.outcome, Outcome::Diverged { tick: 1, .. }));
        assert_eq!(run.fault.map(|f| f.tick), Some(5));
    }

    /// Regression: a missed realtime tick was recorded with the next state's τᵃ and the previous
    /// reply's s, N̂ and u, as if the controller had answered it. Now it has no output, says
    /// why, and only the torque metrics see the torque the drives held.
    #[test]
    fn regression_missed_tick_has_no_invented_controller_output() {
        let mut rec = Recorder::new(Law::Tdc, 10);
        let missed = TelemetryMsg {
            flags: wire::TEL_MISSED | wire::TEL_HELD,
            ..TelemetryMsg::default()
        };
        // Tick 0 answered; tick 1 missed; tick 2 skipped (tick 3's reply skipped one state);
        // tick 3 answered; tick 4 answered late.
        assert!(rec.tick(&state(0, 0.0, 1.0), Some(&reply(0, 2.0, 0)), &Vec3::zeros()));
        rec.applied(None);
        assert!(rec.tick(&state(1, 0.0, 2.0), None, &Vec3::zeros()));
        rec.applied(Some(&missed));
        assert!(rec.tick(&state(2, 0.0, 2.0), None, &Vec3::zeros()));
        rec.applied(Some(&missed));
        assert!(rec.tick(&state(3, 0.0, 2.0), Some(&reply(3, 5.0, 1)), &Vec3::zeros()));
        rec.applied(None);
        assert!(rec.tick(&state(4, 0.0, 5.0), Some(&reply(4, 6.0, 0)), &Vec3::zeros()));
        rec.applied(Some(&missed));
        let run = rec.finish(Some(&state(5, 0.0, 5.0)));
        let fates: Vec<_> = run.records.iter().map(|r| r.fate).collect();
        use ReplyFate::*;
        assert_eq!(fates, [Applied, Missed, Skipped, Applied, Late]);
        assert!(run.records[1].out.is_none() && run.records[2].out.is_none());
        assert_eq!(run.records[1].tau, Vec3::repeat(2.0), "held τᵃ_2");
        assert_eq!(
            run.records[4].tau,
            Vec3::repeat(6.0),
            "a late reply keeps its own τ"
        );
        assert!(run.records[1].held && !run.records[0].held);
    }
}
