//! What a run leaves behind: one [`TickRecord`] per control tick, the state after the last tick,
//! and how the run ended. Every loop mode fills a [`Recorder`] the same way, so divergence is
//! decided in one place.

use deltaloop_controller::Output;
use deltaloop_plant::{PlantSample, Vec3};
use deltaloop_protocol::Law;

/// Error bound of the divergence rule, rad (controller spec: |e_i| > 0.5 rad).
pub const DIVERGENCE_ERR_RAD: f64 = 0.5;

/// One control tick.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TickRecord {
    /// The plant sample the controller saw (tick k, q, q̇, τᵃ_k).
    pub sample: PlantSample,
    /// The plant's true (noise-free) joint rates q̇_k, rad/s: the TDE ground truth.
    pub qd_true: Vec3,
    /// The true joint angles q_k, rad.
    pub q_true: Vec3,
    /// The controller's answer at tick k.
    pub out: Output,
    /// Some joint was clamped over [t_k, t_{k+1}).
    pub clamped: bool,
    /// The plant held the previous torque over [t_k, t_{k+1}) (missed or rejected command).
    pub held: bool,
    /// The plant rejected the command (non-finite, or over the limit under `reject`).
    pub rejected: bool,
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
}

/// A finished run of one law.
#[derive(Clone, Debug)]
pub struct LawRun {
    pub law: Law,
    /// Ticks 0..=last, in order.
    pub records: Vec<TickRecord>,
    /// The plant state after the last recorded tick (tick last + 1), if the plant got there.
    pub after: Option<(PlantSample, Vec3)>,
    pub outcome: Outcome,
    /// A loop fault: its tick and cause. Kept even when the divergence rule ended the trace first
    /// (e.g. the robot drifting while the plant held the torque of a dead controller).
    pub fault: Option<(u64, String)>,
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
                after: None,
                outcome: Outcome::Completed,
                fault: None,
            },
        }
    }

    /// Records tick k (its sample, truth and controller output). Returns false, having marked the
    /// run diverged, if the tick breaks the divergence rule; the caller must stop.
    pub fn tick(
        &mut self,
        sample: PlantSample,
        q_true: Vec3,
        qd_true: Vec3,
        q_des: &Vec3,
        out: Output,
    ) -> bool {
        self.run.records.push(TickRecord {
            sample,
            q_true,
            qd_true,
            out,
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
        } else if !out.tau.iter().all(|x| x.is_finite()) {
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

    /// Marks how the drives treated the last recorded tick's command.
    pub fn applied(&mut self, clamped: bool, held: bool, rejected: bool) {
        if let Some(r) = self.run.records.last_mut() {
            r.clamped = clamped;
            r.held = held;
            r.rejected = rejected;
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
    pub fn fault(&mut self, tick: u64, cause: String) {
        self.run.fault = Some((tick, cause));
        self.run.outcome = Outcome::Faulted;
    }

    /// Stores the state after the last tick and returns the run.
    pub fn finish(mut self, after: Option<(PlantSample, Vec3)>) -> LawRun {
        self.run.after = after;
        self.run
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tick(rec: &mut Recorder, k: u64, q: f64) -> bool {
        let sample = PlantSample {
            k,
            q: Vec3::repeat(q),
            qd: Vec3::zeros(),
            tau_applied: Vec3::zeros(),
        };
        rec.tick(
            sample,
            sample.q,
            sample.qd,
            &Vec3::zeros(),
            Output::default(),
        )
    }

    #[test]
    fn a_fault_ends_an_otherwise_healthy_trace() {
        let mut rec = Recorder::new(Law::Tdc, 10);
        rec.fault(3, "controller died".into());
        assert!(tick(&mut rec, 0, 0.0) && tick(&mut rec, 1, 0.0));
        let run = rec.finish(None);
        assert_eq!(run.outcome, Outcome::Faulted);
        assert_eq!(run.fault, Some((3, "controller died".into())));
    }

    /// The robot can drift out of bounds while the plant holds a dead controller's torque: the
    /// run is diverged, and the fault that caused it stays on record (once patched on afterwards).
    #[test]
    fn fault_kept_when_divergence_ends_the_trace_first() {
        let mut rec = Recorder::new(Law::Tdc, 10);
        rec.fault(5, "controller died".into());
        assert!(tick(&mut rec, 0, 0.0));
        assert!(!tick(&mut rec, 1, 2.0 * DIVERGENCE_ERR_RAD));
        let run = rec.finish(None);
        assert!(matches!(run.outcome, Outcome::Diverged { tick: 1, .. }));
        assert_eq!(run.fault, Some((5, "controller died".into())));
    }
}
