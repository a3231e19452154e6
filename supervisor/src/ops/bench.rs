//! `deltaloop bench plant`: how many wall seconds the plant needs per simulated second.

use anyhow::{Context, Result};
use deltaloop_config::{Law, RunConfig};
use deltaloop_model::{DeltaRobot, Plant, SimConfig, Vec3};
use deltaloop_runner::inproc;
use deltaloop_runner::lawrun::Keep;
use deltaloop_study::Study;
use std::path::{Path, PathBuf};
use std::time::Instant;

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

/// `bench plant`'s motion: the spec's MuJoCo cross-check (docs/delta-robot.md §7.3), from rest
/// at IK(0.05, −0.03, −0.40) under τ = G(q0) + [0.3, −0.2, 0.1], restarted from rest every 0.3 s.
struct Motion {
    robot: DeltaRobot,
    q0: Vec3,
    tau: Vec3,
    cfg: SimConfig,
    /// Control ticks in all, and between restarts.
    ticks: u64,
    segment: u64,
}

impl Motion {
    fn new(seconds: f64) -> Result<Self> {
        let robot = DeltaRobot::default();
        let q0 = robot.ik(&Vec3::new(0.05, -0.03, -0.40))?;
        let tau = robot.gravity(&robot.pose(&q0)?) + Vec3::new(0.3, -0.2, 0.1);
        let cfg = SimConfig::default();
        let ticks = ((seconds / cfg.ts).round() as u64).max(1);
        Ok(Self {
            robot,
            q0,
            tau,
            cfg,
            ticks,
            segment: 1000, // 0.3 s
        })
    }

    /// Simulated seconds the motion covers.
    fn sim_s(&self) -> f64 {
        self.ticks as f64 * self.cfg.ts
    }
}

/// What one measurement of the plant alone gives.
struct PlantTiming {
    wall_per_sim_s: f64,
    /// q (rad) at the end of the first segment.
    q_segment: Vec3,
}

/// Wall seconds per simulated second of the plant alone over the [`Motion`]. RK4 with
/// h = Ts/10 through `Plant::advance`, as in every run. Timed per segment, as MuJoCo is: one
/// clock reading before and one after its ticks, the restart from rest (`Plant::new`) outside.
fn plant_only(m: &Motion, friction: bool) -> Result<PlantTiming> {
    let cfg = SimConfig { friction, ..m.cfg };
    let (mut elapsed, mut q_segment, mut done) = (0.0, None, 0);
    while done < m.ticks {
        let n = m.segment.min(m.ticks - done);
        let mut plant = Plant::new(m.robot.clone(), cfg, 100.0, 0, m.q0)?;
        let t0 = Instant::now();
        for _ in 0..n {
            plant.advance(Some(m.tau))?;
        }
        elapsed += t0.elapsed().as_secs_f64();
        q_segment.get_or_insert(std::hint::black_box(plant.sample()).q);
        done += n;
    }
    Ok(PlantTiming {
        wall_per_sim_s: elapsed / m.sim_s(),
        q_segment: q_segment.unwrap_or(m.q0),
    })
}

/// MuJoCo's half of the measurement: `examples/mujoco-plant/bench.py` run by a python with the
/// pinned `mujoco`.
pub struct Mujoco {
    python: PathBuf,
    script: PathBuf,
}

/// The script, looked for in the current folder's checkout and then in the one this executable
/// was built from.
const MUJOCO_SCRIPT: &str = "examples/mujoco-plant/bench.py";
/// The virtual environment `cargo test` builds (python/requirements.txt, MuJoCo pinned).
const TEST_VENV_PYTHON: &str = "target/python-venv/bin/python";

fn checkouts() -> Vec<PathBuf> {
    let mut roots = vec![PathBuf::from(".")];
    if let Some(built) = Path::new(env!("CARGO_MANIFEST_DIR")).parent() {
        roots.push(built.to_path_buf());
    }
    roots
}

impl Mujoco {
    /// `python` if given (an error if the script is missing), else the tests' venv if it exists.
    /// `Ok(Err(line))`, the line to print, when there is nothing to run.
    pub fn find(python: Option<PathBuf>) -> Result<std::result::Result<Self, String>> {
        let root = checkouts()
            .into_iter()
            .find(|r| r.join(MUJOCO_SCRIPT).is_file());
        match (python, root) {
            (Some(python), Some(root)) => Ok(Ok(Self {
                python,
                script: root.join(MUJOCO_SCRIPT),
            })),
            (Some(python), None) => anyhow::bail!(
                "--mujoco {}: {MUJOCO_SCRIPT} is neither under the current folder nor in the checkout this deltaloop was built from; run from the checkout",
                python.display()
            ),
            (None, root) => match root.map(|r| (r.join(TEST_VENV_PYTHON), r)) {
                Some((python, root)) if python.is_file() => Ok(Ok(Self {
                    python,
                    script: root.join(MUJOCO_SCRIPT),
                })),
                _ => Ok(Err(format!(
                    "MuJoCo: skipped (no {TEST_VENV_PYTHON}: `cargo test --test e2e mujoco_plant::` builds it from python/requirements.txt, or pass --mujoco PYTHON with mujoco installed)"
                ))),
            },
        }
    }

    /// Steps MuJoCo over the motion; its wall seconds per simulated second, q after the first
    /// segment and its version.
    fn measure(&self, m: &Motion) -> Result<(f64, Vec3, String)> {
        let n = u64::from(m.cfg.substeps);
        let h = m.cfg.ts / f64::from(m.cfg.substeps);
        let mut cmd = std::process::Command::new(&self.python);
        // `--name=a,b,c`: a negative value after a space would read as an option. `{:e}` prints
        // the shortest digits that read back as the same f64.
        let list = |v: &Vec3| {
            v.iter()
                .map(|x| format!("{x:e}"))
                .collect::<Vec<_>>()
                .join(",")
        };
        cmd.arg(&self.script)
            .arg(format!("--q0={}", list(&m.q0)))
            .arg(format!("--tau={}", list(&m.tau)));
        cmd.args(["--steps", &(m.ticks * n).to_string()])
            .args(["--segment-steps", &(m.segment * n).to_string()])
            .args(["--h", &format!("{h:e}")]);
        let out = cmd
            .output()
            .with_context(|| format!("cannot run {}", self.python.display()))?;
        let stdout = String::from_utf8_lossy(&out.stdout);
        if !out.status.success() {
            anyhow::bail!(
                "{} {} failed ({}): {}",
                self.python.display(),
                self.script.display(),
                out.status,
                String::from_utf8_lossy(&out.stderr).trim()
            );
        }
        let line = stdout.lines().last().unwrap_or_default();
        let v: serde_json::Value = serde_json::from_str(line)
            .with_context(|| format!("{}: not its JSON line: `{line}`", self.script.display()))?;
        let num = |x: &serde_json::Value| x.as_f64().filter(|x| x.is_finite());
        let wall = num(&v["wall_per_sim_s"]).filter(|&x| x > 0.0);
        let q: Option<Vec<f64>> = v["q_segment"]
            .as_array()
            .and_then(|a| a.iter().map(num).collect());
        match (wall, q.as_deref()) {
            (Some(wall), Some(&[q1, q2, q3])) => Ok((
                wall,
                Vec3::new(q1, q2, q3),
                v["mujoco"].as_str().unwrap_or("?").to_string(),
            )),
            _ => anyhow::bail!("{}: unexpected output `{line}`", self.script.display()),
        }
    }
}

/// Measures and prints; the last line is `plant_wall_per_sim_s=<x> loop_wall_per_sim_s=<y>`,
/// followed by ` mujoco_wall_per_sim_s=<z> ratio=<z/x>` when MuJoCo ran (`mujoco`: Err holds the
/// line saying why not). Each repeat measures the plant, the loop and MuJoCo in turn, so that
/// the machine's drift affects all of them.
pub fn plant(
    seconds: f64,
    repeats: u32,
    mujoco: std::result::Result<Mujoco, String>,
) -> Result<()> {
    let study = s1_hold_study("bench", seconds)?;
    let ts = study.config.loop_.ts_s;
    let motion = Motion::new(seconds)?;
    println!(
        "deltaloop bench plant: {seconds} s simulated per repeat, RK4 h = {:.0} us, {repeats} repeats, median reported",
        ts / f64::from(study.config.plant.substeps) * 1e6
    );
    let (mut plant_t, mut friction_t, mut loop_t, mut mujoco_t) =
        (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    let (mut q_gap, mut version) = (0.0f64, String::new());
    for _ in 0..repeats {
        let p = plant_only(&motion, false)?;
        plant_t.push(p.wall_per_sim_s);
        friction_t.push(plant_only(&motion, true)?.wall_per_sim_s);
        // Whole in-process loop on S1 + hold with friction: reference lookup, tdc-is-sta, plant, recording.
        let t0 = Instant::now();
        let run = inproc::run_law(&study, Law::TdcIsSta, &Keep::default())?;
        let sim_s = (run.end.records as f64) * ts;
        loop_t.push(t0.elapsed().as_secs_f64() / sim_s);
        std::hint::black_box(&run);
        if let Ok(mj) = &mujoco {
            let (wall, q, v) = mj.measure(&motion)?;
            mujoco_t.push(wall);
            q_gap = q_gap.max((q - p.q_segment).amax());
            version = v;
        }
    }
    let fmt = |xs: &[f64]| {
        xs.iter()
            .map(|x| format!("{x:.5}"))
            .collect::<Vec<_>>()
            .join(" ")
    };
    let plant_med = median(plant_t.clone());
    println!(
        "plant only, no friction  wall/sim s per repeat: {}  (median {plant_med:.5})",
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
    let mujoco_med = match &mujoco {
        Ok(mj) => {
            let med = median(mujoco_t.clone());
            println!(
                "MuJoCo {version} ({}, same model, motion and RK4 step, friction off, only mj_step timed) wall/sim s per repeat: {}  (median {med:.5})",
                mj.python.display(),
                fmt(&mujoco_t)
            );
            println!(
                "MuJoCo against deltaloop, q after the first 0.3 s: max |dq| = {q_gap:.1e} rad (soft forearm constraint, 6 coordinates against 3)"
            );
            println!(
                "MuJoCo / deltaloop plant, one core each, friction off: {:.1}x",
                med / plant_med
            );
            Some(med)
        }
        Err(why) => {
            println!("{why}");
            None
        }
    };
    println!(
        "target: plant < 0.025 wall s per simulated s; machine: {} logical CPUs",
        std::thread::available_parallelism().map_or(0, |n| n.get())
    );
    let mut last = format!(
        "plant_wall_per_sim_s={plant_med:.5} loop_wall_per_sim_s={:.5}",
        median(loop_t)
    );
    if let Some(med) = mujoco_med {
        last += &format!(
            " mujoco_wall_per_sim_s={med:.5} ratio={:.2}",
            med / plant_med
        );
    }
    println!("{last}");
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
