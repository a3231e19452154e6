//! The in-process loop: the plant's and the controller's tick ([`PlantSide`], [`ControllerSide`])
//! stepped together in one thread. The process modes run the very same two ticks; only the
//! transport between them differs, and every mode records through the same [`Recorder`].
//!
//! [`PlantSide`]: deltaloop_plant::PlantSide
//! [`ControllerSide`]: deltaloop_controller::ControllerSide
//! [`Recorder`]: crate::record::Recorder

use crate::loops::lawrun::{self, Keep, LawRun};
use crate::study::Study;
use anyhow::Result;
use deltaloop_config::Law;
use deltaloop_plant::Arrival;

/// Runs one law over the study's reference, ticks 0..=N, then takes the final state N + 1.
/// Fails only if the trace cannot be written.
pub fn run_law(study: &Study, law: Law, keep: &Keep) -> Result<LawRun> {
    run_law_through(study, law, keep, study.reference.n as u64)
}

/// [`run_law`] over ticks 0..=`last` only (all of them when `last` ≥ N): the in-process twin of
/// a measured run that covered fewer ticks than its scenario planned.
pub fn run_law_through(study: &Study, law: Law, keep: &Keep, last: u64) -> Result<LawRun> {
    let reference = &study.reference;
    let last = usize::try_from(last).unwrap_or(usize::MAX).min(reference.n);
    let mut rec = lawrun::recorder(study, law, keep)?;
    let mut plant = match study.plant_side() {
        Ok(p) => p,
        Err(e) => {
            rec.plant_failed(e.to_string());
            return lawrun::finish(rec, None);
        }
    };
    let mut ctrl = study.controller_side(law);
    for k in 0..=last {
        if crate::loops::signals::interrupted() {
            rec.interrupt();
            return lawrun::finish(rec, None);
        }
        let state = plant.state();
        let reply = ctrl.answer(&state, &reference.row(k).joint);
        if !rec.tick(&state, Some(&reply)) {
            return lawrun::finish(rec, None);
        }
        match plant.advance(Arrival::Reply(reply)) {
            Ok(tel) => rec.applied(Some(&tel)),
            Err(stop) => {
                rec.plant_failed(stop.cause().to_string());
                return lawrun::finish(rec, None);
            }
        }
    }
    let after = (last == reference.n).then(|| plant.state());
    lawrun::finish(rec, after.as_ref())
}

/// Runs several laws, each on its own thread (they share nothing but the read-only study), each
/// with what `keep(law)` asks for.
pub fn run_laws(study: &Study, laws: &[Law], keep: impl Fn(Law) -> Keep) -> Vec<Result<LawRun>> {
    std::thread::scope(|scope| {
        let handles: Vec<_> = laws
            .iter()
            .map(|&law| {
                let keep = keep(law);
                scope.spawn(move || run_law(study, law, &keep))
            })
            .collect();
        handles
            .into_iter()
            .map(|h| h.join().expect("law thread panicked"))
            .collect()
    })
}
