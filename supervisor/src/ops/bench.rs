//! `deltaloop bench plant`: how many wall seconds the plant needs per simulated second.

use crate::loops::inproc;
use crate::loops::lawrun::Keep;
use crate::study::Study;
use anyhow::Result;
use deltaloop_config::{Law, RunConfig};
use deltaloop_model::{DeltaRobot, Plant, SimConfig, Vec3};
use std::time::Instant;

/// clap parser for a positive duration in seconds.
pub fn parse_positive_seconds(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(v) if v.is_finite() && v > 0.0 && v <= 3600.0 => Ok(v),
        _ => Err(format!(
            "`{s}` is not a duration: expected seconds, 0 < s <= 3600"
        )),
    }
}

fn median(mut xs: Vec<f64>) -> f64 {
    xs.sort_by(f64::total_cmp);
    xs[xs.len() / 2]
}

/// The benchmarks' study, named `name`: S1 (0.8 s) followed by a hold, `seconds` of simulated
/// time in total (at least the motion), friction on, one law (`tdc-is-sta`).
pub fn s1_hold_study(name: &str, seconds: f64) -> Result<Study> {
    let text = format!(
        "name = \"{name}\"\n[scenario]\npath = \"s1\"\nhold_s = {}\n[plant]\nfriction = true\n[controller]\nlaws = [\"tdc-is-sta\"]\n",
        (seconds - 0.8).max(0.0)
    );
    Ok(Study::new(RunConfig::from_toml_str(&text, None)?)?)
}

/// Wall seconds per simulated second of the plant alone: the spec's MuJoCo cross-check motion
/// (from rest at IK(0.05, −0.03, −0.40) under τ = G(q0) + [0.3, −0.2, 0.1], 0.3 s), repeated from
/// rest until `seconds` are covered. RK4 with h = Ts/10 through `Plant::advance`, as in every run.
fn plant_only(seconds: f64, friction: bool) -> Result<f64> {
    let robot = DeltaRobot::default();
    let q0 = robot.ik(&Vec3::new(0.05, -0.03, -0.40))?;
    let tau = robot.gravity(&robot.pose(&q0)?) + Vec3::new(0.3, -0.2, 0.1);
    let cfg = SimConfig {
        friction,
        ..SimConfig::default()
    };
    let segment = 1000; // 0.3 s
    let ticks = (seconds / cfg.ts).round() as u64;
    let mut plant = Plant::new(robot.clone(), cfg, 100.0, 0, q0)?;
    let mut elapsed = 0.0;
    for k in 0..ticks {
        if k % segment == 0 {
            std::hint::black_box(plant.sample());
            plant = Plant::new(robot.clone(), cfg, 100.0, 0, q0)?;
        }
        let t0 = Instant::now();
        plant.advance(Some(tau))?;
        elapsed += t0.elapsed().as_secs_f64();
    }
    std::hint::black_box(plant.sample());
    Ok(elapsed / seconds)
}

/// Measures and prints; the last line is `plant_wall_per_sim_s=<x> loop_wall_per_sim_s=<y>`.
pub fn plant(seconds: f64, repeats: u32) -> Result<()> {
    let study = s1_hold_study("bench", seconds)?;
    let ts = study.config.loop_.ts_s;
    println!(
        "deltaloop bench plant: {seconds} s simulated per repeat, RK4 h = {:.0} us, {repeats} repeats, median reported",
        ts / f64::from(study.config.plant.substeps) * 1e6
    );
    let (mut plant_t, mut friction_t, mut loop_t) = (Vec::new(), Vec::new(), Vec::new());
    for _ in 0..repeats {
        plant_t.push(plant_only(seconds, false)?);
        friction_t.push(plant_only(seconds, true)?);
        // Whole in-process loop on S1 + hold with friction: reference lookup, tdc-is-sta, plant, recording.
        let t0 = Instant::now();
        let run = inproc::run_law(&study, Law::TdcIsSta, &Keep::default())?;
        let sim_s = (run.end.records as f64) * ts;
        loop_t.push(t0.elapsed().as_secs_f64() / sim_s);
        std::hint::black_box(&run);
    }
    let fmt = |xs: &[f64]| {
        xs.iter()
            .map(|x| format!("{x:.5}"))
            .collect::<Vec<_>>()
            .join(" ")
    };
    println!(
        "plant only, no friction  wall/sim s per repeat: {}",
        fmt(&plant_t)
    );
    println!(
        "plant only, friction on  wall/sim s per repeat: {}  (median {:.5})",
        fmt(&friction_t),
        median(friction_t.clone())
    );
    println!(
        "inproc loop (S1, tdc-is-sta, friction) wall/sim s per repeat: {}",
        fmt(&loop_t)
    );
    println!(
        "target: plant < 0.025 wall s per simulated s; machine: {} logical CPUs",
        std::thread::available_parallelism().map_or(0, |n| n.get())
    );
    println!(
        "plant_wall_per_sim_s={:.5} loop_wall_per_sim_s={:.5}",
        median(plant_t),
        median(loop_t)
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn s1_hold_study_keeps_the_name_and_covers_the_seconds() {
        let s = s1_hold_study("bench-loop", 2.0).unwrap();
        assert_eq!(s.config.name, "bench-loop");
        assert_eq!(s.config.controller.laws, vec![Law::TdcIsSta]);
        assert!(s.config.plant.friction);
        assert!((s.config.scenario.hold_s - 1.2).abs() < 1e-12);
        // Shorter than the motion: no hold, never negative.
        assert_eq!(
            s1_hold_study("bench", 0.1).unwrap().config.scenario.hold_s,
            0.0
        );
    }
}
