//! The in-process loop: plant and controller libraries stepped together in one thread. The
//! process modes run the very same `Plant::advance` and `Controller::step`; only the transport
//! between them differs.

use crate::record::{LawRun, Recorder};
use crate::study::Study;
use deltaloop_controller::Measurement;
use deltaloop_protocol::Law;

/// Runs one law over the study's reference, ticks 0..=N.
pub fn run_law(study: &Study, law: Law) -> LawRun {
    let reference = &study.reference;
    let n = reference.n;
    let mut rec = Recorder::new(law, n);
    let mut plant = match study.new_plant() {
        Ok(p) => p,
        Err(e) => {
            rec.plant_failed(e.to_string());
            return rec.finish(None);
        }
    };
    let mut ctrl = study.new_controller(law);
    for row in &reference.rows[..=n] {
        if crate::signals::interrupted() {
            rec.interrupt();
            return rec.finish(None);
        }
        let truth = plant.sample();
        let sample = plant.measure();
        let out = ctrl.step(
            &Measurement {
                q: sample.q,
                qd: sample.qd,
                tau_applied: sample.tau_applied,
            },
            &row.joint,
        );
        if !rec.tick(sample, truth.q, truth.qd, &row.joint.q, out) {
            return rec.finish(None);
        }
        match plant.advance(Some(out.tau)) {
            Ok(a) => rec.applied(a.clamped, a.held, a.rejected),
            Err(e) => {
                rec.plant_failed(e.to_string());
                return rec.finish(None);
            }
        }
    }
    let after = plant.sample();
    rec.finish(Some((after, after.qd)))
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
