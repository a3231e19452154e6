//! The in-process loop: the plant's and the controller's tick ([`PlantSide`], [`ControllerSide`])
//! stepped together in one thread over an arrival schedule: every reply at once (the in-process
//! mode), or what a recorded run's trace says (`deltaloop replay`). The process modes run the
//! very same two ticks; only the transport between them differs, and every mode records through
//! the same [`Recorder`].
//!
//! [`PlantSide`]: deltaloop_plant::PlantSide
//! [`ControllerSide`]: deltaloop_controller::ControllerSide
//! [`Recorder`]: deltaloop_study::record::Recorder

use crate::lawrun::{self, Keep, LawRecorder, LawRun};
use anyhow::Result;
use deltaloop_config::Law;
use deltaloop_model::Vec3;
use deltaloop_plant::{Arrival, PlantSide, PlantStop};
use deltaloop_plant_tick::ReplyOutcome;
use deltaloop_study::Study;
use deltaloop_study::record::metrics::LawMetrics;
use deltaloop_study::record::{Fault, FaultKind};
use deltaloop_transport::wire::{self, TelemetryMsg};

/// Runs one law over the study's reference, ticks 0..=N, then takes the final state N + 1.
/// Fails only if the trace cannot be written.
pub fn run_law(study: &Study, law: Law, keep: &Keep) -> Result<LawRun> {
    run_law_through(study, law, keep, study.reference.n as u64)
}

/// [`run_law`] over ticks 0..=`last` only (all of them when `last` ≥ N): the in-process twin of
/// a measured run that covered fewer ticks than its scenario planned.
pub fn run_law_through(study: &Study, law: Law, keep: &Keep, last: u64) -> Result<LawRun> {
    run_from(study, law, keep, last, study.reference.q0())
}

/// The round-off twins of a law's in-process run: the same run with the plant starting one ulp
/// away, in each of the ways [`Study::twin_q0s`] lists; only the metrics are kept. How far their
/// metrics drift from the run's says how many of its digits survive round-off (see
/// [`deltaloop_study::record::sensitivity`]).
pub fn run_twins_of(study: &Study, law: Law) -> Result<Vec<LawMetrics>> {
    run_twin_jobs(study, &[law])
        .pop()
        .unwrap_or_else(|| Ok(Vec::new()))
}

/// Every law's round-off twins, all of them on every core; per law, in `laws`' order.
pub fn run_twins(study: &Study, laws: &[Law]) -> Vec<Result<Vec<LawMetrics>>> {
    run_twin_jobs(study, laws)
}

fn run_twin_jobs(study: &Study, laws: &[Law]) -> Vec<Result<Vec<LawMetrics>>> {
    let q0s = study.twin_q0s();
    let jobs: Vec<(Law, Vec3)> = laws
        .iter()
        .flat_map(|&l| q0s.iter().map(move |&q| (l, q)))
        .collect();
    let threads = std::thread::available_parallelism().map_or(1, |n| n.get());
    let last = study.reference.n as u64;
    let mut done = crate::pool::map(&jobs, threads, |&(law, q0)| {
        run_from(study, law, &Keep::default(), last, q0).map(|r| r.metrics)
    })
    .into_iter();
    laws.iter()
        .map(|_| done.by_ref().take(q0s.len()).collect())
        .collect()
}

/// `run(job)` for every job (one a law), each on its own thread (they share nothing but the
/// read-only study), in the jobs' order.
fn on_threads<J: Send>(
    jobs: Vec<J>,
    run: impl Fn(J) -> Result<LawRun> + Sync,
) -> Vec<Result<LawRun>> {
    std::thread::scope(|scope| {
        let run = &run;
        let handles: Vec<_> = jobs
            .into_iter()
            .map(|job| scope.spawn(move || run(job)))
            .collect();
        handles
            .into_iter()
            .map(|h| h.join().expect("law thread panicked"))
            .collect()
    })
}

/// Ticks 0..=`last` with the plant at rest at `q0` (rad, joint space) at tick 0.
fn run_from(study: &Study, law: Law, keep: &Keep, last: u64, q0: Vec3) -> Result<LawRun> {
    let last = last.min(study.reference.n as u64);
    let mut rec = lawrun::recorder(study, law, keep)?;
    let plant = match study.plant_side_at(q0) {
        Ok(p) => p,
        Err(e) => {
            rec.plant_failed(e.to_string());
            return lawrun::finish(rec, None);
        }
    };
    run_schedule(study, law, rec, plant, &mut Ideal { last })
}

/// The arrival schedule of one law's run: what happened at each tick, in order.
pub trait Schedule {
    /// What became of the reply to tick `k`; None: the run ended before it.
    fn outcome(&mut self, k: u64) -> Result<Option<ReplyOutcome>>;
    /// Ctrl-C / SIGTERM end the loop (recorded as interrupted) before the next tick.
    fn interruptible(&self) -> bool;
}

/// Every tick 0..=`last` answered and applied at once: the in-process loop.
struct Ideal {
    last: u64,
}

impl Schedule for Ideal {
    fn outcome(&mut self, k: u64) -> Result<Option<ReplyOutcome>> {
        Ok((k <= self.last).then_some(ReplyOutcome::Applied(0)))
    }

    fn interruptible(&self) -> bool {
        true
    }
}

/// Steps the plant's and the controller's ticks together over `schedule`, recording into `rec`;
/// after tick N the state N + 1 closes the record. The in-process loop and the replay of a
/// recorded run are this loop over different schedules.
pub fn run_schedule<'a>(
    study: &'a Study,
    law: Law,
    mut rec: LawRecorder<'a>,
    mut plant: PlantSide,
    schedule: &mut dyn Schedule,
) -> Result<LawRun> {
    let mut ctrl = study.controller_side(law);
    let mut skipped_before = 0u64;
    let mut last = None;
    loop {
        let k = plant.tick();
        let Some(outcome) = schedule.outcome(k)? else {
            break;
        };
        if schedule.interruptible() && crate::signals::interrupted() {
            rec.interrupt();
            return lawrun::finish(rec, None);
        }
        let state = plant.state();
        let row = |j: u64| {
            study
                .reference
                .try_row(j as usize)
                .map(|r| r.joint)
                .map_err(|e| anyhow::anyhow!("the reference at tick {j}: {e}"))
        };
        let reference = row(k)?;
        // A compensated law reads the rows of the time its reply acts, k + d and k + d + 1, or
        // past the reference's last row (N + 1, the last the process modes' controller
        // receives) that row.
        let ahead = match ctrl.lookahead() {
            None => None,
            Some(d) => Some(
                study
                    .reference
                    .rows_ahead(k, d)
                    .map_err(|e| anyhow::anyhow!("the reference ahead of tick {k}: {e}"))?,
            ),
        };
        let (reply, arrival) = match outcome {
            ReplyOutcome::Applied(_) | ReplyOutcome::Late => {
                let mut reply = match &ahead {
                    None => ctrl.answer(&state, &reference),
                    Some((row, next)) => ctrl.answer_ahead(&state, row, next),
                };
                reply.skipped = std::mem::take(&mut skipped_before);
                (Some(reply), outcome.arrival(reply))
            }
            ReplyOutcome::Skipped => {
                skipped_before += 1;
                (None, Arrival::Missed)
            }
            ReplyOutcome::Missed => {
                skipped_before = 0;
                (None, Arrival::Missed)
            }
        };
        last = Some(k);
        // A trace that cannot be written (a full disk) ends the run at its first failed write.
        if !rec.tick(&state, reply.as_ref()) || rec.sink().failed() {
            return lawrun::finish(rec, None);
        }
        match plant.advance(arrival) {
            Ok(tel) => rec.applied(Some(&tel)),
            Err(stop) => {
                // The failed interval's reply and arrival are recorded, as the process modes
                // record the telemetry the plant sends before DIVERGED.
                if let Some(tel) = stop.failed_interval() {
                    rec.applied(Some(tel));
                }
                end_on(&mut rec, stop);
                return lawrun::finish(rec, None);
            }
        }
    }
    // A run that reached its last tick N closes with the state N + 1.
    let after = (last == Some(study.reference.n as u64)).then(|| plant.state());
    lawrun::finish(rec, after.as_ref())
}

/// How the plant's stop ends the record. A controller-silence stop is the loop fault the
/// process modes call it (regression: in-process it was recorded as a divergence), and its tick,
/// whose reply missed the budget like the ones before it, reads late (or missed) and held.
fn end_on(rec: &mut LawRecorder<'_>, stop: PlantStop) {
    match stop {
        PlantStop::ControllerSilent { tick, cause } => {
            rec.applied(Some(&TelemetryMsg {
                tick,
                flags: wire::TEL_MISSED | wire::TEL_HELD,
                ..TelemetryMsg::default()
            }));
            rec.fault(Fault {
                tick,
                kind: FaultKind::ControllerSilent,
                cause,
            });
        }
        other => rec.plant_failed(other.cause().to_string()),
    }
}

/// Runs several laws, each on its own thread, each with what `keep(law)` asks for.
pub fn run_laws(study: &Study, laws: &[Law], keep: impl Fn(Law) -> Keep) -> Vec<Result<LawRun>> {
    let jobs = laws.iter().map(|&law| (law, keep(law))).collect();
    on_threads(jobs, |(law, keep)| run_law(study, law, &keep))
}
