//! What a run leaves behind: one [`TickRecord`] per control tick, streamed to a [`TickSink`] as
//! soon as it is final, and how the run ended ([`RunEnd`]). Every loop mode feeds the same
//! [`Recorder`] the same three message streams (state, reply, telemetry, tick by tick and in
//! order), so a row of `trace.csv`, the divergence rule and every metric come from one place
//! whatever the transport, and memory does not grow with the run.

pub mod metrics;
pub mod sensitivity;
pub mod stats;

use crate::reference::{JointReference, RefRow};
use deltaloop_config::Law;
use deltaloop_controller_tick::ControllerSide;
use deltaloop_law::Output;
use deltaloop_model::{PlantSample, Vec3};
use deltaloop_wire::{self as wire, StateMsg, TelemetryMsg, TorqueMsg};
use std::collections::VecDeque;

/// Error bound of the divergence rule, rad (docs/controllers.md: |e_i| > 0.5 rad).
pub const DIVERGENCE_ERR_RAD: f64 = 0.5;

/// What became of the controller's reply to tick k: declared with its outcome in the plant's
/// tick, where the in-process loop's arrival schedule and the plant take it.
pub use deltaloop_plant_tick::ReplyFate;

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
    /// When the command reached the drives, A_k − t_k (ns: transport delay plus, in realtime, its
    /// measured latency); None if it was not applied or the telemetry was not seen.
    pub arrival_ns: Option<u64>,
    /// False when the plant's telemetry of this tick was expected and not seen: what the plant
    /// did with the reply and the drives is then unknown (`trace.csv` says `unknown`, not a guess).
    pub telemetry: bool,
    /// A compensated law's learned inertia M̂ after tick k, per joint, kg m² ([`Shadow`]); None
    /// for the other laws, and from a reply the supervisor did not see on.
    pub m_hat: Option<Vec3>,
}

/// The supervisor's copy of a compensated built-in law, stepped on the states the controller
/// answered, with the reference rows it read: the law is deterministic, so its M̂ is the
/// controller's own, in every mode, as long as its torque is the reply's to the bit. A reply the
/// supervisor did not see (a state the copy did not step on), or a controller that is not the
/// built-in law, makes the torques part: from then on M̂ is unknown, not a guess.
pub struct Shadow {
    side: ControllerSide,
    /// d, the look-ahead of the law's reference rows.
    lookahead: u64,
    /// Still stepping as the controller did.
    alive: bool,
}

impl Shadow {
    /// A copy of `side`, a compensated law before its first tick; None for a law that is not
    /// compensated.
    pub fn of(side: ControllerSide) -> Option<Self> {
        Some(Self {
            lookahead: side.lookahead()?,
            side,
            alive: true,
        })
    }

    /// Steps on state k as the controller did; its M̂ after it if its torque is the reply's.
    fn step(
        &mut self,
        reference: &JointReference,
        state: &StateMsg,
        reply: &TorqueMsg,
    ) -> Option<Vec3> {
        if !self.alive {
            return None;
        }
        let Ok((row, next)) = reference.rows_ahead(state.tick, self.lookahead) else {
            self.alive = false;
            return None;
        };
        let mine = self.side.answer_ahead(state, &row, &next);
        let same = mine
            .tau
            .iter()
            .zip(&reply.tau)
            .all(|(a, b)| a.to_bits() == b.to_bits());
        self.alive = same;
        self.side.m_hat().filter(|_| same)
    }
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

/// A loop fault: the tick it happened at, what kind of fault, and a one-line cause.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Fault {
    pub tick: u64,
    pub kind: FaultKind,
    pub cause: String,
}

deltaloop_names::text_enum! {
    "snake_case", "status";
    /// How a run ended, as `summary.json` (`status`), `sweep.csv` (`status`) and the exit code of
    /// `deltaloop run` say it. One value per law, derived from its [`RunEnd`] by
    /// [`RunEnd::status`]; the words are the serde names.
    #[derive(Default)]
    pub enum RunStatus {
        /// Every tick 0..=N ran and was recorded.
        #[default]
        Ok,
        /// The divergence rule ended the run (error above the bound, a non-finite value, the robot
        /// left its workspace): a result of the physics, not a failure of the run.
        Diverged,
        /// A loop process was stopped on request by someone other than this supervisor (it exited
        /// with its stopped code, e.g. after a SIGTERM from outside): [`FaultKind::Stopped`].
        Stopped,
        /// The loop ran to its end, but the supervisor lost ticks of the stream or of the plant's
        /// telemetry: every tick it saw is recorded. (`lost-data` in sweeps before the status was
        /// the run's own: still read.)
        #[serde(alias = "lost-data")]
        LostData,
        /// Ctrl-C / SIGTERM to the supervisor stopped the run; the ticks before it are kept.
        Interrupted,
        /// A loop fault ended the run (a process died, stalled, or the plant stopped the loop):
        /// [`Fault::kind`] says which.
        Fault,
        /// The run could not start or finish (set-up, files): no metrics. Only sweep rows carry it;
        /// a run folder's summary has no entry for such a law.
        Error,
    }
}

impl RunStatus {
    /// Whether the run's end is the physics' own (`ok`, `diverged`) and not the loop's (a fault,
    /// an interrupt, lost data): only such a run is repeatable in-process, e.g. by its round-off
    /// twin.
    pub fn is_physical(self) -> bool {
        matches!(self, RunStatus::Ok | RunStatus::Diverged)
    }
}

deltaloop_names::text_enum! {
    "snake_case", "fault kind";
    /// What kind of loop fault ended a run (`summary.json` `fault_kind`). The cause text says the
    /// rest (exit status, the process's last log line, timings).
    pub enum FaultKind {
        /// The plant stopped the loop (FAULT) because the controller did not answer
        /// `faults.controller_silence_ticks` ticks in a row (stalled, too slow, or gone), and braked.
        ControllerSilent,
        /// The controller exited with its fault code (e.g. a reference row missing when due).
        ControllerFailed,
        /// The controller panicked.
        ControllerPanicked,
        /// The controller was killed by a signal.
        ControllerKilled,
        /// The controller exited with any other status.
        ControllerExited,
        /// The plant exited with its fault code without having sent a FAULT.
        PlantFailed,
        /// The plant panicked.
        PlantPanicked,
        /// The plant was killed by a signal.
        PlantKilled,
        /// The plant exited with any other status.
        PlantExited,
        /// The plant exited normally (status 0) before the end of the run.
        PlantQuit,
        /// The plant stopped the loop (OVERRUN) because its own process woke later than
        /// `loop.overrun_after_us` with `loop.overrun = "fault"` (the host stalled it), and braked.
        PlantOverrun,
        /// The plant stopped the loop (PLANT_ERROR) because its own physics reported an error (a
        /// foreign plant's `truth` or `measure` failed): not the law's divergence; it braked.
        PlantError,
        /// A loop process exited with its set-up failure code.
        Setup,
        /// A loop process stopped on request (its stopped code) that this supervisor never made.
        Stopped,
        /// The plant's process sent nothing for `loop.silence_timeout_ms` (stopped, or starved
        /// by its host) and the controller gave up on it (it exited with `EXIT_PEER_SILENT`).
        PlantStalled,
        /// The controller did not exit after the plant's final state: the supervisor stopped it.
        ControllerHung,
        /// The plant did not exit after the controller had: the supervisor stopped it.
        PlantHung,
        /// Neither loop process exited when the run ended: the supervisor stopped both.
        Hung,
    }
}

impl FaultKind {
    /// The run status a fault of this kind gives.
    pub fn status(self) -> RunStatus {
        match self {
            FaultKind::Stopped => RunStatus::Stopped,
            _ => RunStatus::Fault,
        }
    }
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
    /// Stopped by the loop fault in [`RunEnd::fault`] (a process died, stalled, or the plant failed).
    Faulted,
    /// The loop ran to its end, but the supervisor lost ticks of the stream (it fell behind the
    /// loop; its queues overflowed): [`RunEnd::lost_ticks`] of them, the first at
    /// [`RunEnd::first_lost`]; or ticks came without the plant's telemetry
    /// ([`RunEnd::no_telemetry`]). Every tick it saw is recorded.
    LostData,
}

/// How a law's recording ended: everything but the ticks themselves (those went to the sink).
#[derive(Clone, Debug, PartialEq)]
pub struct RunEnd {
    pub law: Law,
    /// Ticks recorded (handed to the sink).
    pub records: u64,
    /// Ticks the supervisor never saw (its queues overflowed): not recorded.
    pub lost_ticks: u64,
    /// The first lost tick, if any.
    pub first_lost: Option<u64>,
    /// Ticks recorded without the plant's telemetry (the plant did not send it, or the
    /// supervisor's queue lost it), and the first of them.
    pub no_telemetry: u64,
    pub first_no_telemetry: Option<u64>,
    /// Ticks recorded with their reply unknown because the near bridge of a remote controller
    /// said the reply may have been lost on the link and could not be recovered
    /// (`REPLIES_LOST`), and the first of them.
    pub replies_lost: u64,
    pub first_reply_lost: Option<u64>,
    /// Replies for a tick that already had one: the first is recorded (the plant applies the
    /// first), the others counted here.
    pub duplicate_replies: u64,
    /// Replies the controller's own transport refused (`REPLIES_REFUSED`: a ROS 2 node's bad
    /// commands), and its count of each cause.
    pub refused_replies: u64,
    pub refused_replies_why: Option<String>,
    /// Ticks whose applied reply carried a publish stamp the plant could not believe
    /// (`TEL_STAMP_REPLACED`): the plant used its own receive time.
    pub stamps_replaced: u64,
    pub outcome: Outcome,
    /// A loop fault. Kept even when the divergence rule ended the trace first (e.g. the robot
    /// drifting while the plant held the torque of a dead controller).
    pub fault: Option<Fault>,
}

impl RunEnd {
    /// How the run ended, in one word. An interrupt comes first (the run did not finish,
    /// whatever else happened), then a loop fault (a stop on a fault is not a divergence, even
    /// when the robot drifted past the bound while the plant held the torque of a silent
    /// controller), then the divergence rule, then lost data.
    pub fn status(&self) -> RunStatus {
        match (&self.outcome, &self.fault) {
            (Outcome::Interrupted { .. }, _) => RunStatus::Interrupted,
            (_, Some(f)) => f.kind.status(),
            (Outcome::Diverged { .. }, None) => RunStatus::Diverged,
            (Outcome::LostData, None) => RunStatus::LostData,
            (Outcome::Completed, None) => RunStatus::Ok,
            // A fault outcome always has its fault on record.
            (Outcome::Faulted, None) => RunStatus::Fault,
        }
    }

    /// The tick the status names: where the run was interrupted, faulted or diverged, or the
    /// first tick whose data was lost; None for `ok`.
    pub fn status_tick(&self) -> Option<u64> {
        match (&self.outcome, &self.fault) {
            (Outcome::Interrupted { tick }, _) => Some(*tick),
            (_, Some(f)) => Some(f.tick),
            (Outcome::Diverged { tick, .. }, None) => Some(*tick),
            (Outcome::LostData, None) => [
                self.first_lost,
                self.first_no_telemetry,
                self.first_reply_lost,
            ]
            .into_iter()
            .flatten()
            .min(),
            (Outcome::Completed | Outcome::Faulted, None) => None,
        }
    }

    /// Why, in one line, for every status but `ok` (`summary.json` `reason`, `sweep.csv`
    /// `reason`).
    pub fn reason(&self) -> Option<String> {
        let nonempty = |s: &str| Some(s.to_string()).filter(|s| !s.trim().is_empty());
        match (&self.outcome, &self.fault) {
            (Outcome::Interrupted { tick }, _) => Some(format!("interrupted at tick {tick}")),
            (outcome, Some(f)) => {
                let text = nonempty(&f.cause).unwrap_or_else(|| "loop fault".into());
                // The fault text usually names its tick already; otherwise say it.
                let at = if text.contains(&format!("tick {}", f.tick)) {
                    String::new()
                } else {
                    format!("fault at tick {}: ", f.tick)
                };
                let drift = match outcome {
                    Outcome::Diverged { tick, reason } => format!(
                        " (the tracking error had passed the divergence bound at tick {tick}: {})",
                        nonempty(reason).unwrap_or_else(|| "diverged".into())
                    ),
                    _ => String::new(),
                };
                Some(format!("{at}{text}{drift}"))
            }
            (Outcome::Diverged { tick, reason }, None) => Some(
                nonempty(reason)
                    .unwrap_or_else(|| format!("diverged at tick {tick} (no reason recorded)")),
            ),
            (Outcome::LostData, None) => Some(self.lost_data_text()),
            (Outcome::Completed | Outcome::Faulted, None) => None,
        }
    }

    /// What a run that lost data lost: ticks of the stream, the plant's telemetry, or both.
    pub fn lost_data_text(&self) -> String {
        let mut parts = Vec::new();
        if let Some(first) = self.first_lost {
            parts.push(format!(
                "the supervisor lost {} ticks of the stream, the first at tick {first}: it fell behind the loop and its queues overflowed",
                self.lost_ticks
            ));
        }
        if let Some(first) = self.first_no_telemetry {
            parts.push(format!(
                "{} ticks came without the plant's telemetry, the first at tick {first} (the plant did not send it, or the supervisor's queue lost it): their `reply` and `drives` are `unknown` and they are missing from the timing",
                self.no_telemetry
            ));
        }
        if let Some(first) = self.first_reply_lost {
            parts.push(format!(
                "{} ticks' replies from the controller on the other host may have been lost on the link and could not be recovered, the first at tick {first}: their `reply` and `drives` are `unknown`",
                self.replies_lost
            ));
        }
        parts.push("every tick the supervisor saw is recorded".into());
        parts.join("; ")
    }
}

/// Where finished ticks go, in tick order (the trace file, the streaming metrics, …).
pub trait TickSink {
    /// Tick k is final: its record, its reference row and the TDE truth
    /// N_k = (q̇_{k+1} − q̇_k)/Ts − τᵃ_{k+1}/M̄ (rad/s², true rates; None if tick k + 1 is unknown).
    fn take(&mut self, r: &TickRecord, row: &RefRow, n_true: Option<Vec3>);

    /// Tick k as soon as it is recorded with what the plant did (its telemetry), before it is
    /// final: a later reply may still mark a missed reply skipped, and its TDE truth waits for
    /// the next tick. For live views, which should not wait [`OPEN_TICKS`] ticks.
    fn recorded(&mut self, _r: &TickRecord, _row: &RefRow) {}
}

/// Ticks kept open after they are recorded: a later reply can still mark them skipped (a
/// controller skips at most a few states: its queue holds `LOOP_BUFFER`), and the next tick
/// completes the held torque and the TDE truth. Older ticks go to the sink.
pub const OPEN_TICKS: usize = 64;

/// Collects ticks, applies the divergence rule and streams finished ticks to a [`TickSink`].
/// Holds [`OPEN_TICKS`] ticks at most, whatever the run's length.
pub struct Recorder<'a, S: TickSink> {
    ticks: OpenTicks<'a>,
    sink: S,
}

/// The recorder's state and rules, apart from its sink: its methods are not generic, so they are
/// compiled (and optimised) here once, not again in each crate that names a sink type.
struct OpenTicks<'a> {
    reference: &'a JointReference,
    m_bar: f64,
    open: VecDeque<(TickRecord, RefRow)>,
    /// The newest open tick went to [`TickSink::recorded`].
    told: bool,
    last_k: Option<u64>,
    end: RunEnd,
    shadow: Option<Shadow>,
}

impl<'a, S: TickSink> Recorder<'a, S> {
    /// A recorder for `law` over `reference`; `m_bar` (kg m²) is the M̄ of the TDE truth.
    pub fn new(law: Law, reference: &'a JointReference, m_bar: f64, sink: S) -> Self {
        Self {
            ticks: OpenTicks::new(law, reference, m_bar),
            sink,
        }
    }

    /// Records each tick's M̂ of a compensated law through `shadow` ([`TickRecord::m_hat`]).
    pub fn with_shadow(mut self, shadow: Option<Shadow>) -> Self {
        self.ticks.shadow = shadow;
        self
    }

    /// Records tick k: the state the plant published and the controller's reply to it (None: it
    /// never answered this state). Returns false, having marked the run diverged, if the tick
    /// breaks the divergence rule; the caller must stop. Call [`Recorder::applied`] next.
    pub fn tick(&mut self, state: &StateMsg, reply: Option<&TorqueMsg>) -> bool {
        self.ticks.tick(state, reply, &mut self.sink)
    }

    /// Where the finished ticks go.
    pub fn sink(&self) -> &S {
        &self.sink
    }

    /// Where the finished ticks go.
    pub fn sink_mut(&mut self) -> &mut S {
        &mut self.sink
    }

    /// The controller's transport refused `n` replies in all (`why`: each cause's count).
    pub fn refused_replies(&mut self, n: u64, why: String) {
        self.ticks.end.refused_replies = n;
        self.ticks.end.refused_replies_why = Some(why);
    }

    /// `n` replies came for ticks that already had one (the first was kept).
    pub fn duplicate_replies(&mut self, n: u64) {
        self.ticks.end.duplicate_replies += n;
    }

    /// Tick k never reached the supervisor (its queues overflowed while it was not draining): it
    /// is counted, and has no row.
    pub fn lost(&mut self, k: u64) {
        self.ticks.lost(k);
    }

    /// Marks what the plant did over the last recorded tick, from its telemetry (None: not seen,
    /// counted: the tick's fates are unknown).
    pub fn applied(&mut self, tel: Option<&TelemetryMsg>) {
        self.ticks.applied(tel);
        self.ticks.tell(&mut self.sink);
    }

    /// The last recorded tick's reply may have been lost on the link (`REPLIES_LOST`): whether
    /// the controller answered it is unknown, so its `reply` and `drives` are `unknown`, and it
    /// is counted.
    pub fn reply_lost(&mut self) {
        self.ticks.reply_lost();
        self.ticks.tell(&mut self.sink);
    }

    /// `n` ticks from `first` whose replies may have been lost on the link were recorded before
    /// the supervisor heard so (their rows say what was seen): counted all the same.
    pub fn replies_lost_at(&mut self, first: u64, n: u64) {
        let end = &mut self.ticks.end;
        end.replies_lost += n;
        end.first_reply_lost = Some(end.first_reply_lost.map_or(first, |f| f.min(first)));
    }

    /// The plant failed while integrating the last recorded tick (e.g. left the workspace).
    pub fn plant_failed(&mut self, reason: String) {
        self.ticks.plant_failed(reason);
    }

    /// The run was interrupted by a signal after the last recorded tick.
    pub fn interrupt(&mut self) {
        self.ticks.interrupt();
    }

    /// The loop faulted at `fault.tick`. It ends the run as [`Outcome::Faulted`] unless something
    /// else ended the trace (divergence, an interrupt), before or after; the fault is kept either
    /// way.
    pub fn fault(&mut self, fault: Fault) {
        self.ticks.fault(fault);
    }

    /// Takes the state after the last tick (N + 1, or wherever the plant stopped), if the plant
    /// got there, closes every open tick and returns how the run ended, with the sink.
    pub fn finish(mut self, after: Option<&StateMsg>) -> (RunEnd, S) {
        let end = self.ticks.finish(after, &mut self.sink);
        (end, self.sink)
    }
}

impl<'a> OpenTicks<'a> {
    fn new(law: Law, reference: &'a JointReference, m_bar: f64) -> Self {
        Self {
            reference,
            m_bar,
            open: VecDeque::with_capacity(OPEN_TICKS + 1),
            told: true,
            last_k: None,
            shadow: None,
            end: RunEnd {
                law,
                records: 0,
                lost_ticks: 0,
                first_lost: None,
                no_telemetry: 0,
                first_no_telemetry: None,
                replies_lost: 0,
                first_reply_lost: None,
                duplicate_replies: 0,
                refused_replies: 0,
                refused_replies_why: None,
                stamps_replaced: 0,
                outcome: Outcome::Completed,
                fault: None,
            },
        }
    }

    fn tick(
        &mut self,
        state: &StateMsg,
        reply: Option<&TorqueMsg>,
        sink: &mut dyn TickSink,
    ) -> bool {
        let sample = measured(state);
        self.hold_previous(sample.k, sample.tau_applied);
        // A reply for tick k says how many older states the controller skipped to reach it.
        if let Some(r) = reply {
            let skipped = usize::try_from(r.skipped).unwrap_or(usize::MAX);
            let oldest = state.tick.saturating_sub(r.skipped);
            for (prev, _) in self.open.iter_mut().rev().take(skipped) {
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
        let row = self.reference.row(sample.k as usize);
        let m_hat = match (&mut self.shadow, reply) {
            (Some(shadow), Some(r)) => shadow.step(self.reference, state, r),
            _ => None,
        };
        let record = TickRecord {
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
            arrival_ns: None,
            telemetry: true,
            m_hat,
        };
        self.push(record, row, sink);
        let e = row.joint.q - sample.q;
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
                self.end.outcome = Outcome::Diverged {
                    tick: sample.k,
                    reason,
                };
                false
            }
            None => true,
        }
    }

    /// Opens a tick; the oldest open tick goes to the sink once more than [`OPEN_TICKS`] are open.
    fn push(&mut self, record: TickRecord, row: RefRow, sink: &mut dyn TickSink) {
        self.tell(sink);
        self.last_k = Some(record.sample.k);
        self.end.records += 1;
        self.open.push_back((record, row));
        self.told = false;
        if self.open.len() > OPEN_TICKS {
            self.close_oldest(None, sink);
        }
    }

    /// Hands the newest open tick to [`TickSink::recorded`], unless it went there already.
    fn tell(&mut self, sink: &mut dyn TickSink) {
        if !self.told
            && let Some((r, row)) = self.open.back()
        {
            sink.recorded(r, row);
        }
        self.told = true;
    }

    /// Hands the oldest open tick to the sink, with its TDE truth from the tick after it (the
    /// next open one, else `after`).
    fn close_oldest(&mut self, after: Option<&(PlantSample, Vec3)>, sink: &mut dyn TickSink) {
        let Some((r, row)) = self.open.pop_front() else {
            return;
        };
        let k = r.sample.k;
        let next = match self.open.front() {
            Some((n, _)) => (n.sample.k == k + 1).then_some((n.qd_true, n.sample.tau_applied)),
            None => after
                .filter(|(s, _)| s.k == k + 1)
                .map(|(s, qd)| (*qd, s.tau_applied)),
        };
        let ts = self.reference.ts;
        let n_true = next.map(|(qd1, tau1)| (qd1 - r.qd_true) / ts - tau1 / self.m_bar);
        sink.take(&r, &row, n_true);
    }

    /// A tick without a reply counts the torque the drives held over it: τᵃ of the next state
    /// (tick `next`; nothing is patched across a lost tick).
    fn hold_previous(&mut self, next: u64, tau_next: Vec3) {
        if let Some((prev, _)) = self.open.back_mut()
            && prev.out.is_none()
            && prev.sample.k + 1 == next
        {
            prev.tau = tau_next;
        }
    }

    /// Tick k never reached the supervisor (its queues overflowed while it was not draining): it
    /// is counted, and has no row.
    fn lost(&mut self, k: u64) {
        self.end.lost_ticks += 1;
        self.end.first_lost.get_or_insert(k);
    }

    /// Marks what the plant did over the last recorded tick, from its telemetry (None: not seen,
    /// counted: the tick's fates are unknown).
    fn applied(&mut self, tel: Option<&TelemetryMsg>) {
        let flags = tel.map_or(0, |m| m.flags);
        let unanswered = wire::TEL_MISSED | wire::TEL_SAFE_STOP;
        if tel.is_some()
            && flags & unanswered == 0
            && self.open.back().is_some_and(|(r, _)| r.out.is_none())
        {
            // The plant applied a reply the record never got (its copy came after the tick was
            // finished, or a queue on its way overflowed): the controller stepped here, so the
            // row cannot say "missed" (regression: a near bridge held up 3 s left 1,870 such
            // rows, the run `ok` and its replay differing).
            self.reply_lost();
            return;
        }
        if let Some((r, _)) = self.open.back_mut() {
            r.telemetry = tel.is_some();
            if tel.is_none() {
                self.end.no_telemetry += 1;
                self.end.first_no_telemetry.get_or_insert(r.sample.k);
            }
            if flags & wire::TEL_STAMP_REPLACED != 0 {
                self.end.stamps_replaced += 1;
            }
            r.clamped = flags & wire::TEL_CLAMPED != 0;
            r.held = flags & wire::TEL_HELD != 0;
            r.rejected = flags & wire::TEL_REJECTED != 0;
            if r.out.is_some() && flags & wire::TEL_MISSED != 0 {
                r.fate = ReplyFate::Late;
            }
            r.arrival_ns = tel
                .filter(|m| m.flags & wire::TEL_MISSED == 0)
                .map(|m| m.arrival_ns);
        }
    }

    /// See [`Recorder::reply_lost`]: as a tick without telemetry, counted apart.
    fn reply_lost(&mut self) {
        if let Some((r, _)) = self.open.back_mut() {
            (r.telemetry, r.arrival_ns) = (false, None);
            (r.clamped, r.held, r.rejected) = (false, false, false);
            self.end.replies_lost += 1;
            self.end.first_reply_lost.get_or_insert(r.sample.k);
        }
    }

    /// The tick after the last recorded one (0 before any).
    fn next_tick(&self) -> u64 {
        self.last_k.map_or(0, |k| k + 1)
    }

    /// The plant failed while integrating the last recorded tick (e.g. left the workspace).
    fn plant_failed(&mut self, reason: String) {
        let tick = self.next_tick();
        self.end.outcome = Outcome::Diverged { tick, reason };
    }

    /// The run was interrupted by a signal after the last recorded tick.
    fn interrupt(&mut self) {
        let tick = self.next_tick();
        self.end.outcome = Outcome::Interrupted { tick };
    }

    /// The loop faulted at `fault.tick`. It ends the run as [`Outcome::Faulted`] unless something
    /// else ended the trace (divergence, an interrupt), before or after; the fault is kept either
    /// way.
    fn fault(&mut self, fault: Fault) {
        self.end.fault = Some(fault);
        if self.end.outcome == Outcome::Completed {
            self.end.outcome = Outcome::Faulted;
        }
    }

    /// Takes the state after the last tick (N + 1, or wherever the plant stopped), if the plant
    /// got there, closes every open tick and returns how the run ended, with the sink.
    fn finish(mut self, after: Option<&StateMsg>, sink: &mut dyn TickSink) -> RunEnd {
        self.tell(sink);
        let after = after.map(|s| {
            let sample = measured(s);
            self.hold_previous(sample.k, sample.tau_applied);
            (sample, Vec3::from(s.qd_true))
        });
        while !self.open.is_empty() {
            self.close_oldest(after.as_ref(), sink);
        }
        if self.end.outcome == Outcome::Completed
            && (self.end.first_lost.is_some()
                || self.end.no_telemetry > 0
                || self.end.replies_lost > 0)
        {
            self.end.outcome = Outcome::LostData;
        }
        self.end
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scenario::TaskPath;
    use deltaloop_config::RunConfig;
    use deltaloop_model::DeltaRobot;

    type Ticks = Vec<(TickRecord, Option<Vec3>)>;

    impl TickSink for Ticks {
        fn take(&mut self, r: &TickRecord, _: &RefRow, n_true: Option<Vec3>) {
            self.push((*r, n_true));
        }
    }

    fn reference() -> JointReference {
        let cfg =
            RunConfig::from_toml_str("name = \"t\"\n[scenario]\npath = \"s1\"\n", None).unwrap();
        let path = TaskPath::from_section(&cfg.scenario);
        JointReference::build(&DeltaRobot::default(), &path, 3e-4, 0.0).unwrap()
    }

    /// State k at the reference plus `dq` rad on every joint.
    fn state(r: &JointReference, k: u64, dq: f64, tau_applied: f64) -> StateMsg {
        let q: [f64; 3] = (r.row(k as usize).joint.q + Vec3::repeat(dq)).into();
        StateMsg {
            tick: k,
            q,
            q_true: q,
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

    fn tick(rec: &mut Recorder<'_, Ticks>, r: &JointReference, k: u64, dq: f64) -> bool {
        rec.tick(&state(r, k, dq, 0.0), Some(&reply(k, 0.0, 0)))
    }

    #[test]
    fn a_fault_ends_an_otherwise_healthy_trace() {
        let r = reference();
        let mut rec = Recorder::new(Law::Tdc, &r, 1.0, Ticks::new());
        let fault = Fault {
            tick: 3,
            kind: FaultKind::ControllerKilled,
            cause: "controller died".into(),
        };
        rec.fault(fault.clone());
        assert!(tick(&mut rec, &r, 0, 0.0) && tick(&mut rec, &r, 1, 0.0));
        let (end, ticks) = rec.finish(None);
        assert_eq!(end.outcome, Outcome::Faulted);
        assert_eq!(end.fault, Some(fault));
        assert_eq!((end.records, ticks.len()), (2, 2));
    }

    fn end(outcome: Outcome, fault: Option<Fault>) -> RunEnd {
        let r = reference();
        let mut rec = Recorder::new(Law::Tdc, &r, 1.0, Ticks::new());
        rec.ticks.end.outcome = outcome;
        rec.ticks.end.fault = fault;
        rec.finish(None).0
    }

    /// Each way a run ends has its status, tick and reason; a fault outranks the divergence it
    /// caused, an interrupt outranks both.
    #[test]
    fn status_tick_and_reason_of_each_ending() {
        let slow = Fault {
            tick: 99,
            kind: FaultKind::ControllerSilent,
            cause: "no torque within the budget for 100 consecutive ticks".into(),
        };
        let drift = Outcome::Diverged {
            tick: 120,
            reason: "tracking error 0.6 rad exceeds 0.5 rad".into(),
        };
        let ok = end(Outcome::Completed, None);
        assert_eq!(
            (ok.status(), ok.status_tick(), ok.reason()),
            (RunStatus::Ok, None, None)
        );
        let d = end(drift.clone(), None);
        assert_eq!(
            (d.status(), d.status_tick()),
            (RunStatus::Diverged, Some(120))
        );
        let f = end(Outcome::Faulted, Some(slow.clone()));
        assert_eq!((f.status(), f.status_tick()), (RunStatus::Fault, Some(99)));
        assert_eq!(
            f.reason().unwrap(),
            "fault at tick 99: no torque within the budget for 100 consecutive ticks"
        );
        let fd = end(drift, Some(slow.clone()));
        assert_eq!(
            (fd.status(), fd.status_tick()),
            (RunStatus::Fault, Some(99))
        );
        assert!(
            fd.reason()
                .unwrap()
                .contains("divergence bound at tick 120")
        );
        let i = end(Outcome::Interrupted { tick: 42 }, Some(slow.clone()));
        assert_eq!(
            (i.status(), i.status_tick()),
            (RunStatus::Interrupted, Some(42))
        );
        let stop = Fault {
            kind: FaultKind::Stopped,
            ..slow
        };
        assert_eq!(
            end(Outcome::Faulted, Some(stop)).status(),
            RunStatus::Stopped
        );
        let mut lost = end(Outcome::Completed, None);
        lost.outcome = Outcome::LostData;
        (lost.first_lost, lost.first_no_telemetry) = (Some(7), Some(3));
        assert_eq!(
            (lost.status(), lost.status_tick()),
            (RunStatus::LostData, Some(3))
        );
    }

    /// The serde word of `v` (a unit variant).
    fn serde_word<T: serde::Serialize>(v: T) -> String {
        serde_json::to_value(v)
            .unwrap()
            .as_str()
            .unwrap()
            .to_string()
    }

    /// Every text enum has one word per variant, the same for serde (config, JSON, CSV) and for
    /// `name`/`parse`/"allowed" (strum).
    #[test]
    fn every_text_enum_has_one_word_per_variant() {
        use deltaloop_config::PathKind;
        use deltaloop_config::{LoopMode, Preset};
        use strum::VariantArray;
        fn check<T>()
        where
            T: VariantArray + Copy + Into<&'static str> + serde::Serialize + std::fmt::Debug,
        {
            for &v in T::VARIANTS {
                assert_eq!(serde_word(v), v.into(), "{v:?}");
            }
        }
        check::<Law>();
        check::<Preset>();
        check::<PathKind>();
        check::<LoopMode>();
        check::<RunStatus>();
        check::<FaultKind>();
        check::<ReplyFate>();
        for &f in ReplyFate::VARIANTS {
            assert_eq!(ReplyFate::parse(f.name()), Ok(f));
        }
        assert_eq!(
            deltaloop_names::one_of::<ReplyFate>(),
            "applied, late, skipped or missed"
        );
    }

    /// The words of `summary.json` and `sweep.csv`, and the older sweep word still read.
    #[test]
    fn status_words() {
        use strum::VariantArray;
        let words: Vec<&str> = RunStatus::VARIANTS.iter().map(|s| s.name()).collect();
        assert_eq!(
            words,
            [
                "ok",
                "diverged",
                "stopped",
                "lost_data",
                "interrupted",
                "fault",
                "error"
            ]
        );
        for &s in RunStatus::VARIANTS {
            assert_eq!(serde_json::to_value(s).unwrap(), s.name());
            assert_eq!(RunStatus::parse(s.name()), Ok(s));
        }
        for &k in FaultKind::VARIANTS {
            assert_eq!(serde_json::to_value(k).unwrap(), k.name());
        }
        let old: RunStatus = serde_json::from_str("\"lost-data\"").unwrap();
        assert_eq!(old, RunStatus::LostData);
    }

    /// The robot can drift out of bounds while the plant holds a dead controller's torque: the
    /// run is diverged, and the fault that caused it stays on record, whichever is noticed first.
    #[test]
    fn fault_kept_when_divergence_ends_the_trace_first() {
        let r = reference();
        for fault_first in [true, false] {
            let mut rec = Recorder::new(Law::Tdc, &r, 1.0, Ticks::new());
            let fault = Fault {
                tick: 5,
                kind: FaultKind::ControllerKilled,
                cause: "controller died".into(),
            };
            if fault_first {
                rec.fault(fault.clone());
            }
            assert!(tick(&mut rec, &r, 0, 0.0));
            assert!(!tick(&mut rec, &r, 1, 2.0 * DIVERGENCE_ERR_RAD));
            if !fault_first {
                rec.fault(fault.clone());
            }
            let (end, _) = rec.finish(None);
            assert!(matches!(end.outcome, Outcome::Diverged { tick: 1, .. }));
            assert_eq!(end.fault.map(|f| f.tick), Some(5));
        }
    }

    /// Regression: a missed realtime tick was recorded with the next state's τᵃ and the previous
    /// reply's s, N̂ and u, as if the controller had answered it. Now it has no output, says
    /// why, and only the torque metrics see the torque the drives held.
    #[test]
    fn regression_missed_tick_has_no_invented_controller_output() {
        let r = reference();
        let mut rec = Recorder::new(Law::Tdc, &r, 1.0, Ticks::new());
        let missed = TelemetryMsg {
            flags: wire::TEL_MISSED | wire::TEL_HELD,
            ..TelemetryMsg::default()
        };
        // Tick 0 answered; tick 1 missed; tick 2 skipped (tick 3's reply skipped one state);
        // tick 3 answered; tick 4 answered late.
        assert!(rec.tick(&state(&r, 0, 0.0, 1.0), Some(&reply(0, 2.0, 0))));
        rec.applied(None);
        assert!(rec.tick(&state(&r, 1, 0.0, 2.0), None));
        rec.applied(Some(&missed));
        assert!(rec.tick(&state(&r, 2, 0.0, 2.0), None));
        rec.applied(Some(&missed));
        assert!(rec.tick(&state(&r, 3, 0.0, 2.0), Some(&reply(3, 5.0, 1))));
        rec.applied(None);
        assert!(rec.tick(&state(&r, 4, 0.0, 5.0), Some(&reply(4, 6.0, 0))));
        rec.applied(Some(&missed));
        let (_, ticks) = rec.finish(Some(&state(&r, 5, 0.0, 5.0)));
        let fates: Vec<_> = ticks.iter().map(|(t, _)| t.fate).collect();
        use ReplyFate::*;
        assert_eq!(fates, [Applied, Missed, Skipped, Applied, Late]);
        assert!(ticks[1].0.out.is_none() && ticks[2].0.out.is_none());
        assert_eq!(ticks[1].0.tau, Vec3::repeat(2.0), "held τᵃ_2");
        assert_eq!(
            ticks[4].0.tau,
            Vec3::repeat(6.0),
            "a late reply keeps its own τ"
        );
        assert!(ticks[1].0.held && !ticks[0].0.held);
    }

    /// Regression: with the controller on another host, a reply the plant applied whose copy
    /// reached the supervisor after it had finished the tick (a near bridge held up 3 s) was
    /// recorded "missed": the run was `ok`, and its replay, whose controller did not step there,
    /// differed. The row's reply is `unknown`, counted as a reply lost, and the run lost data.
    #[test]
    fn regression_a_reply_the_plant_applied_that_the_record_lacks_is_unknown() {
        let r = reference();
        let mut rec = Recorder::new(Law::Tdc, &r, 1.0, Ticks::new());
        let applied = TelemetryMsg::default();
        let missed = TelemetryMsg {
            flags: wire::TEL_MISSED | wire::TEL_HELD,
            ..TelemetryMsg::default()
        };
        assert!(tick(&mut rec, &r, 0, 0.0));
        rec.applied(Some(&applied));
        // Applied by the plant, its copy never came.
        assert!(rec.tick(&state(&r, 1, 0.0, 0.0), None));
        rec.applied(Some(&applied));
        // Missed by the plant: a miss.
        assert!(rec.tick(&state(&r, 2, 0.0, 0.0), None));
        rec.applied(Some(&missed));
        assert!(tick(&mut rec, &r, 3, 0.0));
        rec.applied(Some(&applied));
        let (end, ticks) = rec.finish(Some(&state(&r, 4, 0.0, 0.0)));
        assert_eq!(end.outcome, Outcome::LostData);
        assert_eq!((end.replies_lost, end.first_reply_lost), (1, Some(1)));
        let seen: Vec<_> = ticks.iter().map(|(t, _)| (t.telemetry, t.fate)).collect();
        use ReplyFate::*;
        assert_eq!(
            seen,
            [
                (true, Applied),
                (false, Missed),
                (true, Missed),
                (true, Applied)
            ]
        );
    }

    /// Regression: ticks whose telemetry never came were recorded with invented fates and the run
    /// was "ok". Now they are marked, counted, and the run is lost data.
    #[test]
    fn regression_a_tick_without_telemetry_is_marked_and_the_run_lost_data() {
        let r = reference();
        let mut rec = Recorder::new(Law::Tdc, &r, 1.0, Ticks::new());
        let tel = TelemetryMsg::default();
        for k in 0..4 {
            assert!(tick(&mut rec, &r, k, 0.0));
            rec.applied((k < 2).then_some(&tel));
        }
        let (end, ticks) = rec.finish(Some(&state(&r, 4, 0.0, 0.0)));
        assert_eq!(end.outcome, Outcome::LostData);
        assert_eq!((end.no_telemetry, end.first_no_telemetry), (2, Some(2)));
        let seen: Vec<bool> = ticks.iter().map(|(t, _)| t.telemetry).collect();
        assert_eq!(seen, [true, true, false, false]);
    }

    /// A long run streams: no more than OPEN_TICKS ticks are held, every tick reaches the sink in
    /// order with the TDE truth from its successor, and a lost tick leaves a hole without truth.
    #[test]
    fn ticks_stream_in_order_with_their_truth_and_holes_stay_holes() {
        let r = reference();
        let m_bar = 0.5;
        let mut rec = Recorder::new(Law::Tdc, &r, m_bar, Ticks::new());
        let n = 3 * OPEN_TICKS as u64;
        let qd = |k: u64| [k as f64 * 1e-3; 3];
        for k in 0..n {
            if k == 100 {
                rec.lost(k);
                continue;
            }
            let mut s = state(&r, k, 0.0, k as f64);
            s.qd_true = qd(k);
            assert!(rec.tick(&s, Some(&reply(k, 0.0, 0))));
            rec.applied(None);
            assert!(rec.ticks.open.len() <= OPEN_TICKS);
        }
        let mut last = state(&r, n, 0.0, n as f64);
        last.qd_true = qd(n);
        let (end, ticks) = rec.finish(Some(&last));
        assert_eq!(end.outcome, Outcome::LostData);
        assert_eq!(
            (end.lost_ticks, end.first_lost, end.records),
            (1, Some(100), n - 1)
        );
        let ks: Vec<u64> = ticks.iter().map(|(t, _)| t.sample.k).collect();
        assert_eq!(ks, (0..n).filter(|&k| k != 100).collect::<Vec<_>>());
        for (t, truth) in &ticks {
            let k = t.sample.k;
            if k == 99 {
                assert!(truth.is_none(), "no truth across the hole");
                continue;
            }
            let want = (Vec3::from(qd(k + 1)) - Vec3::from(qd(k))) / r.ts
                - Vec3::repeat((k + 1) as f64) / m_bar;
            assert_eq!(*truth, Some(want), "tick {k}");
        }
    }
}
