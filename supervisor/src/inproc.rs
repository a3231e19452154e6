//! The in-process loop: the plant's and the controller's tick ([`PlantSide`], [`ControllerSide`])
//! stepped together in one thread. The process modes run the very same two ticks; only the
//! transport between them differs, and every mode records through the same [`Recorder`].
//!
//! [`PlantSide`]: deltaloop_plant::PlantSide
//! [`ControllerSide`]: deltaloop_controller::ControllerSide

use crate::record::{LawRun, Recorder};
use crate::study::Study;
use deltaloop_config::Law;
use deltaloop_plant::Arrival;

/// Runs one law over the study's reference, ticks 0..=N, then takes the final state N + 1.
pub fn run_law(study: &Study, law: Law) -> LawRun {
    let reference = &study.reference;
    let mut rec = Recorder::new(law, reference.n);
    let mut plant = match study.plant_side() {
        Ok(p) => p,
        Err(e) => {
            rec.plant_failed(e.to_string());
            return rec.finish(None);
        }
    };
    let mut ctrl = study.controller_side(law);
    for row in &reference.rows[..=reference.n] {
        if crate::signals::interrupted() {
            rec.interrupt();
            return rec.finish(None);
        }
        let state = plant.state();
        let reply = ctrl.answer(&state, &row.joint);
        if !rec.tick(&state, Some(&reply), &row.joint.q) {
            return rec.finish(None);
        }
        match plant.advance(Arrival::Reply(reply)) {
            Ok(tel) => rec.applied(Some(&tel)),
            Err(stop) => {
                rec.plant_failed(stop.cause().to_string());
                return rec.finish(None);
            }
        }
    }
    rec.finish(Some(&plant.state()))
}

/// Runs several laws, each on its own thread (they share nothing but the read-only study).
pub fn run_laws(study: &Study, laws: &[Law]) -> Vec<LawRun> {
    std::thread::scope(|scope| {
        let handles: Vec<_> = laws
            .iter()
            .map(|&law| scope.spawn(move || run_law(study, law)))
            .collect();
        handles
            .into_iter()
            .map(|h| h.join().expect("law thread panicked"))
            .collect()
    })
}
