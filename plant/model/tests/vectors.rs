//! Every numeric vector of docs/delta-robot.md §7 (tests/data/delta-robot-vectors.json), compared
//! entry-wise within 1e-9 × max|entry of that quantity|.

use deltaloop_model::{DeltaParams, DeltaRobot, Mat3, PlantSim, SimConfig, Vec3};
use serde_json::Value;

fn data() -> Value {
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../tests/data/delta-robot-vectors.json"
    );
    serde_json::from_str(&std::fs::read_to_string(path).expect("test data")).expect("json")
}

fn v3(v: &Value) -> Vec3 {
    Vec3::from_iterator(v.as_array().unwrap().iter().map(|x| x.as_f64().unwrap()))
}

fn m3(v: &Value) -> Mat3 {
    let rows: Vec<Vec3> = v.as_array().unwrap().iter().map(v3).collect();
    Mat3::from_rows(&[
        rows[0].transpose(),
        rows[1].transpose(),
        rows[2].transpose(),
    ])
}

/// Asserts |got − want| ≤ 1e-9 · max|want| entry-wise.
fn close(what: &str, got: &[f64], want: &[f64]) {
    let scale = want.iter().fold(0.0f64, |m, x| m.max(x.abs()));
    for (i, (g, w)) in got.iter().zip(want).enumerate() {
        assert!(
            (g - w).abs() <= 1e-9 * scale,
            "{what}[{i}]: got {g:.17e}, want {w:.17e} (tol {:.3e})",
            1e-9 * scale
        );
    }
}

fn flat(m: &Mat3) -> Vec<f64> {
    (0..3)
        .flat_map(|r| (0..3).map(move |c| m[(r, c)]))
        .collect()
}

#[test]
fn params_and_derived_match_spec() {
    let d = data();
    let p = DeltaParams::default();
    let ps = &d["params"];
    for (got, key) in [
        (p.base_radius, "R"),
        (p.platform_radius, "r"),
        (p.upper_arm, "La"),
        (p.forearm, "Lb"),
        (p.g, "g"),
        (p.rotor_inertia, "Im"),
        (p.gear_ratio, "n_gear"),
        (p.m_upper_arm, "m_ua"),
        (p.i_upper_arm, "I_ua"),
        (p.l_com, "l_c"),
        (p.m_elbow, "m_el"),
        (p.m_forearm, "m_fa"),
        (p.alpha, "alpha"),
        (p.m_plate, "m_pl"),
        (p.m_pay, "m_pay"),
        (p.fv, "Fv"),
        (p.fc, "Fc"),
        (p.eps_c, "eps_c"),
    ] {
        assert_eq!(got, ps[key].as_f64().unwrap(), "param {key}");
    }
    close("Ib", &[p.ib()], &[d["derived"]["Ib"].as_f64().unwrap()]);
    close("mu", &[p.mu()], &[d["derived"]["mu"].as_f64().unwrap()]);
    close("mn", &[p.mn()], &[d["derived"]["mn"].as_f64().unwrap()]);
}

#[test]
fn configuration_vectors_v1_to_v4() {
    let d = data();
    let robot = DeltaRobot::default();
    for (n, c) in d["configs"].as_array().unwrap().iter().enumerate() {
        let q = v3(&c["q"]);
        let qd = v3(&c["qd"]);
        let qdd = v3(&c["qdd"]);
        let pose = robot.pose(&q).unwrap();
        let tag = |s: &str| format!("V{} {s}", n + 1);
        close(&tag("x"), pose.x.as_slice(), v3(&c["x"]).as_slice());
        close(&tag("J"), &flat(&pose.jacobian()), &flat(&m3(&c["J"])));
        close(&tag("M"), &flat(&robot.mass(&pose)), &flat(&m3(&c["M"])));
        close(
            &tag("Jdot qdot"),
            pose.jdot_qdot(&qd).as_slice(),
            v3(&c["Jdot_qdot"]).as_slice(),
        );
        close(&tag("Jdot"), &flat(&pose.jdot(&qd)), &flat(&m3(&c["Jdot"])));
        close(
            &tag("C"),
            &flat(&robot.coriolis(&pose, &qd)),
            &flat(&m3(&c["C"])),
        );
        close(
            &tag("C qdot"),
            robot.coriolis_qdot(&pose, &qd).as_slice(),
            v3(&c["C_qdot"]).as_slice(),
        );
        close(
            &tag("G"),
            robot.gravity(&pose).as_slice(),
            v3(&c["G"]).as_slice(),
        );
        let tau = robot.inverse_dynamics(&pose, &qd, &qdd);
        close(&tag("tau"), tau.as_slice(), v3(&c["tau_id"]).as_slice());
        // The same torque from the matrix form M q̈ + C q̇ + G.
        let tau_m =
            robot.mass(&pose) * qdd + robot.coriolis(&pose, &qd) * qd + robot.gravity(&pose);
        close(
            &tag("tau (matrix form)"),
            tau_m.as_slice(),
            v3(&c["tau_id"]).as_slice(),
        );
        // Forward dynamics inverts it.
        let back = robot.forward_dynamics(&pose, &qd, &tau).unwrap();
        close(&tag("forward dynamics"), back.as_slice(), qdd.as_slice());
        close(
            &tag("E"),
            &[robot.energy(&pose, &qd)],
            &[c["energy"].as_f64().unwrap()],
        );
    }
}

#[test]
fn inverse_kinematics_vectors() {
    let d = data();
    let robot = DeltaRobot::default();
    for c in d["ik"].as_array().unwrap() {
        let q = robot.ik(&v3(&c["x"])).unwrap();
        close("IK", q.as_slice(), v3(&c["q"]).as_slice());
    }
}

#[test]
fn rk4_vectors_with_and_without_friction() {
    let d = data();
    for c in d["rk4"].as_array().unwrap() {
        let friction = c["friction"].as_bool().unwrap();
        let h = c["h"].as_f64().unwrap();
        let steps = c["steps"].as_u64().unwrap();
        let cfg = SimConfig {
            ts: h,
            substeps: 1,
            friction,
            ..SimConfig::default()
        };
        let mut sim = PlantSim::new(DeltaRobot::default(), cfg, v3(&c["q0"])).unwrap();
        let tau = v3(&c["tau"]);
        // The vector's torque is G(q0) + [0.3, -0.2, 0.1]: check that too.
        let pose = sim.robot().pose(&sim.q()).unwrap();
        close(
            "tau = G(q0) + offset",
            (sim.robot().gravity(&pose) + Vec3::new(0.3, -0.2, 0.1)).as_slice(),
            tau.as_slice(),
        );
        for _ in 0..steps {
            sim.rk4(&tau, h).unwrap();
        }
        close(
            &format!("RK4 q (friction {friction})"),
            sim.q().as_slice(),
            v3(&c["q"]).as_slice(),
        );
        close(
            &format!("RK4 qdot (friction {friction})"),
            sim.qd().as_slice(),
            v3(&c["qd"]).as_slice(),
        );
    }
}

#[test]
fn ten_substeps_of_a_tick_equal_ten_rk4_steps() {
    // The tick step (ZOH over Ts, 10 substeps) is exactly ten RK4 steps of h = Ts/10.
    let robot = DeltaRobot::default();
    let q0 = robot.ik(&Vec3::new(0.05, -0.03, -0.40)).unwrap();
    let tau = Vec3::new(-1.1, -1.4, -1.2);
    let mut a = PlantSim::new(robot.clone(), SimConfig::default(), q0).unwrap();
    let mut b = a.clone();
    a.step(&tau).unwrap();
    for _ in 0..10 {
        b.rk4(&tau, 3e-4 / 10.0).unwrap();
    }
    assert_eq!(a.q(), b.q());
    assert_eq!(a.qd(), b.qd());
    assert_eq!(a.tick(), 1);
}
