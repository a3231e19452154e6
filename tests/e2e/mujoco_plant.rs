//! A plant written in Python joins a deltaloop run: the `deltaloop.Plant` helper (`python/`) and
//! the Delta robot as a MuJoCo model, `examples/mujoco-plant/plant.py`, run with `--plant-cmd`
//! under the built-in `tdc-is-sta` controller.
//!
//! The venv (`target/python-venv`, with MuJoCo) is set up by `tests/common/python.rs`; without
//! Python the tests fail and say what to install.

use crate::common;

use common::python::{python, root, run_cmd, text};
use serde_json::Value;
use std::path::Path;
use std::process::Command;

/// The venv's python and a script as one `--plant-cmd` (split at whitespace by the supervisor).
fn plant_cmd(script: &Path) -> String {
    let py = python().to_str().unwrap().to_string();
    let cmd = format!("{py} {}", script.display());
    assert_eq!(
        cmd.split_whitespace().count(),
        2,
        "--plant-cmd splits at whitespace: move the checkout ({cmd})"
    );
    cmd
}

/// Columns `<name>_1..3` of every row of `law` in a run's trace.csv.
fn trace_columns(out: &Path, law: &str, name: &str) -> Vec<[f64; 3]> {
    let mut r = csv::Reader::from_path(out.join("trace.csv")).unwrap();
    let head = r.headers().unwrap().clone();
    let col = |i: usize| {
        head.iter()
            .position(|h| h == format!("{name}_{i}"))
            .unwrap_or_else(|| panic!("no column {name}_{i} in trace.csv"))
    };
    let (c1, c2, c3, cl) = (col(1), col(2), col(3), head.iter().position(|h| h == "law"));
    r.records()
        .map(|rec| rec.unwrap())
        .filter(|rec| cl.is_none_or(|c| &rec[c] == law))
        .map(|rec| [c1, c2, c3].map(|c| rec[c].parse::<f64>().unwrap()))
        .collect()
}

fn max_abs_diff(a: &[[f64; 3]], b: &[[f64; 3]]) -> f64 {
    assert_eq!(a.len(), b.len(), "traces of different lengths");
    a.iter()
        .zip(b)
        .flat_map(|(x, y)| (0..3).map(move |i| (x[i] - y[i]).abs()))
        .fold(0.0, f64::max)
}

fn max_of(v: &Value) -> f64 {
    v.as_array()
        .unwrap()
        .iter()
        .map(|x| x.as_f64().unwrap())
        .fold(0.0, f64::max)
}

/// The MuJoCo model alone reproduces the model's RK4 vectors (docs/delta-robot.md §7.3: 0.3 s
/// from rest under a constant torque, friction off and on) and the gravity torque at V1.
/// Measured: max |Δq| 3.4e-9 rad (off) and 5.5e-12 rad (on), G within 3.1e-12 N m; asserted
/// 1e-7 rad and 1e-9 N m (a 1 % error in any mass or length gives > 1e-4 rad here).
#[test]
fn the_mujoco_model_reproduces_the_model_vectors() {
    let o = run_cmd(
        Command::new(python())
            .args(["examples/mujoco-plant/plant.py", "--check"])
            .current_dir(root()),
        "plant.py --check",
    );
    let out = text(&o.stdout);
    assert!(o.status.success(), "{out}{}", text(&o.stderr));
    let value_after = |line: &str, key: &str| -> f64 {
        let rest = &line[line.find(key).unwrap_or_else(|| panic!("{key} in {line}")) + key.len()..];
        rest.split_whitespace().next().unwrap().parse().unwrap()
    };
    let rk4: Vec<&str> = out.lines().filter(|l| l.starts_with("RK4")).collect();
    assert_eq!(rk4.len(), 2, "{out}");
    for l in rk4 {
        let dq = value_after(l, "max|Δq| = ");
        assert!(dq < 1e-7, "{l}");
    }
    let g = out
        .lines()
        .find(|l| l.starts_with("holding torque"))
        .expect("holding torque line");
    assert!(value_after(g, "G_spec| = ") < 1e-9, "{g}");
}

/// The MuJoCo plant under the built-in `tdc-is-sta` tracks S1 in lockstep like the built-in plant
/// (measured on S1: max-joint RMS 2.557e-8 vs 2.549e-8 rad, max |e| 6.804e-7 vs 6.799e-7 rad,
/// trajectories 1.0e-9 rad apart, torques 7.7e-4 N m apart of 4.95 N m, forearm length error
/// 2.8e-8 m). Asserted with margin, and tight enough that a wrong torque sign, τᵃ left 0, a
/// missing gravity or a few % of mass error fails: RMS and max |e| within 2 %, trajectories within
/// 1e-6 rad, commanded torques within 0.01 N m, τᵃ_{k+1} = τ_k (MuJoCo's actuator force, reported),
/// forearm length error below 1e-6 m; every tick kept, nothing left behind.
#[test]
fn the_mujoco_plant_tracks_s1_in_lockstep_like_the_builtin_plant() {
    let cmd = plant_cmd(&root().join("examples/mujoco-plant/plant.py"));
    let tmp = tempfile::tempdir().unwrap();
    let (builtin, ours) = (tmp.path().join("builtin"), tmp.path().join("mujoco"));
    let law = "tdc-is-sta";
    let b = common::run(
        "configs/s1-nominal.toml",
        "inproc",
        &builtin,
        &["--law", law],
    );
    let s = common::run(
        "configs/s1-nominal.toml",
        "lockstep",
        &ours,
        &["--law", law, "--plant-cmd", &cmd],
    );
    let log = std::fs::read_to_string(ours.join(format!("{law}.plant.log"))).unwrap_or_default();
    let m = &s["laws"][law];
    assert_eq!(m["completed"], true, "{m}\nplant log:\n{log}");
    assert_eq!(m["lost_ticks"], 0, "{m}");
    let want = &b["laws"][law];
    for key in ["rms_rad", "max_abs_err_rad"] {
        let (w, g) = (max_of(&want[key]), max_of(&m[key]));
        assert!(w > 0.0 && w < 1e-5, "built-in {key} {w}");
        assert!(
            (g - w).abs() <= 0.02 * w,
            "MuJoCo plant {key} {g:e} rad vs built-in {w:e} rad (bound 2 %)\nplant log:\n{log}"
        );
    }
    let dq = max_abs_diff(
        &trace_columns(&ours, law, "q"),
        &trace_columns(&builtin, law, "q"),
    );
    assert!(dq < 1e-6, "trajectories {dq:e} rad apart");
    let (tau, tau_rs) = (
        trace_columns(&ours, law, "tau"),
        trace_columns(&builtin, law, "tau"),
    );
    let dtau = max_abs_diff(&tau, &tau_rs);
    assert!(dtau < 0.01, "commanded torques {dtau:e} N m apart");
    let applied = trace_columns(&ours, law, "tau_applied");
    assert!(applied[1..].iter().all(|a| a.iter().any(|x| x.abs() > 0.1)));
    let lag = max_abs_diff(&applied[1..], &tau[..tau.len() - 1]);
    assert!(lag < 1e-9, "τᵃ_(k+1) differs from τ_k by {lag:e} N m");
    let tendon: f64 = log
        .split("|L − Lb| = ")
        .nth(1)
        .and_then(|r| r.split_whitespace().next())
        .and_then(|x| x.parse().ok())
        .unwrap_or_else(|| panic!("no forearm length error in the plant log:\n{log}"));
    assert!(tendon < 1e-6, "forearm length error {tendon:e} m");
    common::assert_clean(&ours, &s);
}

/// A Python plant whose `step` returns a malformed τᵃ (two entries) at tick 40 ends the run as
/// diverged at tick 41, and the supervisor's error quotes the helper's one line naming it.
#[test]
fn a_python_plant_that_reports_a_bad_tau_applied_is_named() {
    let tmp = tempfile::tempdir().unwrap();
    let script = tmp.path().join("bad_plant.py");
    std::fs::write(
        &script,
        r#"
import sys
from deltaloop import Plant

plant = Plant(name="bad-plant")
q, qd = [0.0] * 3, [0.0] * 3

def start(q0):
    q[:] = q0
    return q, qd, (0.0, 0.0, 0.0)

def step(tau, dt):  # a free rotor per joint, 0.03 kg m²
    if plant.tick == 40:
        return q, qd, (1.0, 2.0)
    for i in range(3):
        qd[i] += tau[i] / 0.03 * dt
        q[i] += qd[i] * dt
    return q, qd, tau

sys.exit(plant.run(start, step))
"#,
    )
    .unwrap();
    let out = tmp.path().join("run");
    let cmd = plant_cmd(&script);
    let o = common::deltaloop(&[
        "run",
        "configs/s1-nominal.toml",
        "--mode",
        "lockstep",
        "--law",
        "tdc-is-sta",
        "--plant-cmd",
        &cmd,
        "--out",
        out.to_str().unwrap(),
    ]);
    let err = text(&o.stderr);
    assert!(!o.status.success(), "{err}");
    assert!(
        err.contains("bad-plant: model failed at tick 41")
            && err.contains("tau_applied has 2 entries, not 3"),
        "{err}"
    );
    let s = common::summary(&out);
    let m = &s["laws"]["tdc-is-sta"];
    assert_eq!(m["completed"], false, "{m}");
    assert_eq!(m["diverged_at_tick"], 41, "{m}");
    assert_eq!(m["lost_ticks"], 0, "{m}");
    common::assert_clean(&out, &s);
}

/// The Python helper's drives (`deltaloop.plant.Drives`) apply the same torque as the built-in
/// plant's (`Plant::advance_after`, docs/delta-robot.md §5.2) over a sequence with a 1.5-tick
/// transport delay, measured latencies (one past the next tick), a missed reply, a non-finite
/// command and one beyond τ_max: τᵃ per interval within 1e-12 N m and the same clamped, held
/// and rejected flags, under both `clamp` and `reject`.
#[test]
fn the_python_drives_apply_what_the_builtin_drives_apply() {
    use deltaloop_model::{DeltaRobot, Plant, SimConfig, Vec3};
    let (ts_ns, delay_ns, tau_max) = (300_000u64, 450_000u64, 100.0);
    let q0 = DeltaRobot::default()
        .ik(&Vec3::new(0.0, 0.0, -0.4))
        .unwrap();
    // (command or none for a miss, latency ns) per tick.
    let hold = {
        let r = DeltaRobot::default();
        r.gravity(&r.pose(&q0).unwrap())
    };
    let cmds: Vec<(Option<[f64; 3]>, u64)> = (0..14u64)
        .map(|k| {
            let off = [0.3 * k as f64, -0.2 * k as f64, 0.1];
            let tau = [hold[0] + off[0], hold[1] + off[1], hold[2] + off[2]];
            match k {
                3 => (Some([f64::NAN, 0.0, 0.0]), 0),
                5 => (Some([150.0, tau[1], tau[2]]), 0),
                7 => (None, 0),
                2 => (Some(tau), 120_000),
                9 => (Some(tau), 400_000),
                _ => (Some(tau), 0),
            }
        })
        .collect();
    for reject in [false, true] {
        let mut plant = Plant::new(
            DeltaRobot::default(),
            SimConfig::default(),
            tau_max,
            delay_ns,
            q0,
        )
        .unwrap()
        .reject_over_limit(reject);
        let rust: Vec<Value> = cmds
            .iter()
            .map(|(c, lat)| {
                let a = plant
                    .advance_after(c.map(Vec3::from), *lat)
                    .expect("advance");
                serde_json::json!([
                    [a.tau[0], a.tau[1], a.tau[2]],
                    a.clamped,
                    a.held,
                    a.rejected
                ])
            })
            .collect();
        let input = serde_json::json!({
            "hold": [hold[0], hold[1], hold[2]],
            "cmds": cmds.iter().map(|(c, lat)| serde_json::json!([
                c.map(|t| t.map(|x| if x.is_nan() { "nan".to_string() } else { format!("{x:e}") })),
                lat
            ])).collect::<Vec<_>>(),
        });
        let out = common::python::py_snippet(&format!(
            r#"
import json
from deltaloop.plant import Drives
inp = json.loads('''{input}''')
d = Drives({tau_max}, {reject}, {delay_ns}, {ts_ns}, inp["hold"])
rows = []
for k, (c, lat) in enumerate(inp["cmds"]):
    if c is not None:
        d.submit(k, [float(x) for x in c], lat)
    pieces, clamped, held, rejected = d.interval(k)
    tau = [sum(length * t[i] for length, t in pieces) / {ts_ns} for i in range(3)]
    rows.append([tau, clamped, held, rejected])
print(json.dumps(rows))
"#,
            reject = if reject { "True" } else { "False" },
        ));
        // The sequence exercises every case: a clamp (under `clamp`), a rejection, a hold, and
        // intervals cut by a command taking effect inside them (τᵃ between two commands).
        let flag = |i: usize| rust.iter().filter(|r| r[i] == true).count();
        assert!((flag(1) > 0) != reject, "clamped: {rust:?}");
        assert!(flag(2) > 0 && flag(3) > 0, "held, rejected: {rust:?}");
        let py: Vec<Value> = serde_json::from_str(&out).unwrap();
        assert_eq!(py.len(), rust.len());
        for (k, (p, r)) in py.iter().zip(&rust).enumerate() {
            for i in 0..3 {
                let (a, b) = (p[0][i].as_f64().unwrap(), r[0][i].as_f64().unwrap());
                assert!(
                    (a - b).abs() < 1e-12,
                    "reject {reject}, tick {k}: τᵃ python {} vs rust {}",
                    p[0],
                    r[0]
                );
            }
            assert_eq!(
                p.as_array().unwrap()[1..],
                r.as_array().unwrap()[1..],
                "reject {reject}, tick {k}: flags (clamped, held, rejected)"
            );
        }
    }
}

/// `bench plant --mujoco PYTHON` times MuJoCo on the built-in plant's motion: the two agree on q
/// after the first 0.3 s (measured 3.4e-9 rad, the `--check` gap; asserted 1e-7 rad, which a
/// different start, torque or step fails by orders of magnitude), and the last line carries
/// MuJoCo's wall seconds per simulated second and the ratio to the plant's.
#[test]
fn bench_plant_times_mujoco_on_the_same_motion() {
    let py = python().to_str().unwrap().to_string();
    let o = run_cmd(
        Command::new(env!("CARGO_BIN_EXE_deltaloop"))
            .args(["bench", "plant", "--seconds", "0.3", "--repeats", "1"])
            .args(["--mujoco", &py])
            .current_dir(root()),
        "bench plant --mujoco",
    );
    let out = text(&o.stdout);
    assert!(o.status.success(), "{out}{}", text(&o.stderr));
    let gap = out
        .lines()
        .find(|l| l.starts_with("MuJoCo against deltaloop"))
        .unwrap_or_else(|| panic!("no q comparison in\n{out}"));
    let dq: f64 = gap
        .split("max |dq| = ")
        .nth(1)
        .and_then(|r| r.split_whitespace().next())
        .and_then(|x| x.parse().ok())
        .unwrap_or_else(|| panic!("{gap}"));
    assert!(dq < 1e-7, "{gap}");
    let last: std::collections::HashMap<&str, f64> = out
        .lines()
        .last()
        .unwrap()
        .split_whitespace()
        .filter_map(|kv| kv.split_once('='))
        .map(|(k, v)| (k, v.parse().unwrap()))
        .collect();
    let (plant, mujoco, ratio) = (
        last["plant_wall_per_sim_s"],
        last["mujoco_wall_per_sim_s"],
        last["ratio"],
    );
    assert!(plant > 0.0 && mujoco > 0.0, "{out}");
    assert!((ratio - mujoco / plant).abs() <= 0.01 * ratio, "{out}");
}
