//! The spec's reference-trajectory vectors (task and joint space) and the scenario peaks.

use deltaloop_config::RunConfig;
use deltaloop_model::{DeltaRobot, Vec3};
use deltaloop_study::reference::joint_sample;
use deltaloop_study::scenario::TaskPath;
use serde_json::Value;

fn v3(v: &Value) -> Vec3 {
    Vec3::from_iterator(v.as_array().unwrap().iter().map(|x| x.as_f64().unwrap()))
}

fn close(what: &str, got: &Vec3, want: &Vec3) {
    let scale = want.amax();
    assert!(
        (got - want).amax() <= 1e-9 * scale,
        "{what}: got {got:?}, want {want:?}"
    );
}

fn path(name: &str) -> TaskPath {
    let cfg = RunConfig::from_toml_str(&format!("[scenario]\npath = \"{name}\"\n"), None).unwrap();
    TaskPath::from_section(&cfg.scenario)
}

#[test]
fn trajectory_vectors_s1_s2_s3() {
    let text = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../tests/data/delta-robot-vectors.json"
    ))
    .unwrap();
    let d: Value = serde_json::from_str(&text).unwrap();
    let robot = DeltaRobot::default();
    let cases = d["trajectory"].as_array().unwrap();
    assert_eq!(cases.len(), 4);
    for c in cases {
        let name = format!("s{}", c["scenario"].as_u64().unwrap());
        let t = c["t"].as_f64().unwrap();
        let task = path(&name).sample(t);
        let tag = |q: &str| format!("{name} t={t} {q}");
        close(&tag("x"), &task.x, &v3(&c["x"]));
        close(&tag("xdot"), &task.xd, &v3(&c["xd"]));
        close(&tag("xddot"), &task.xdd, &v3(&c["xdd"]));
        let j = joint_sample(&robot, &task).unwrap();
        close(&tag("q"), &j.q, &v3(&c["q"]));
        close(&tag("qdot"), &j.qd, &v3(&c["qd"]));
        close(&tag("qddot"), &j.qdd, &v3(&c["qdd"]));
    }
}

#[test]
fn scenario_durations_and_tick_counts() {
    for (name, t, n) in [("s1", 0.8, 2667), ("s2", 0.2, 667), ("s3", 1.2, 4000)] {
        let p = path(name);
        assert!((p.duration() - t).abs() < 1e-15);
        let cfg =
            RunConfig::from_toml_str(&format!("[scenario]\npath = \"{name}\"\n"), None).unwrap();
        assert_eq!(cfg.ticks(p.duration()), n, "{name}");
    }
}

#[test]
fn paths_start_and_end_at_rest_and_hold() {
    for name in ["s1", "s2", "s3"] {
        let p = path(name);
        let start = p.sample(0.0);
        let end = p.sample(p.duration() + 0.05);
        assert!((start.x - Vec3::new(0.25, 0.0, -0.43)).amax() < 1e-15);
        assert!((end.x - Vec3::new(-0.25, 0.0, -0.43)).amax() < 1e-15);
        assert_eq!(start.xd.amax(), 0.0);
        assert!(end.xd.amax() < 1e-15 && end.xdd.amax() < 1e-15);
    }
    // S3 passes P1 at rest at t = 0.6 s (the C² joint of its two segments).
    let mid = path("s3").sample(0.6);
    assert!((mid.x - Vec3::new(0.0, 0.15, -0.43)).amax() < 1e-15 && mid.xd.amax() < 1e-12);
}

#[test]
fn s2_peaks_match_spec() {
    // Spec §6: S2 peaks |ẋ| 7.36 m/s, |ẍ| 167 m/s², |q̇| 36 rad/s, |q̈| 1770 rad/s².
    let robot = DeltaRobot::default();
    let p = path("s2");
    let (mut v, mut a, mut w, mut al) = (0.0f64, 0.0f64, 0.0f64, 0.0f64);
    for k in 0..=667 {
        let s = p.sample(k as f64 * 3e-4);
        let j = joint_sample(&robot, &s).unwrap();
        v = v.max(s.xd.norm());
        a = a.max(s.xdd.norm());
        w = w.max(j.qd.amax());
        al = al.max(j.qdd.amax());
    }
    assert!((v - 7.36).abs() < 0.01, "{v}");
    assert!((a - 167.0).abs() < 1.0, "{a}");
    assert!((w - 36.0).abs() < 0.5, "{w}");
    assert!((al - 1770.0).abs() < 10.0, "{al}");
}
