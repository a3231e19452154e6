//! The property checks of docs/delta-robot.md §7 over the workspace box, and the energy checks E1/E2.

use deltaloop_model::{DeltaRobot, Mat3, PlantSim, SimConfig, Vec3};
use proptest::prelude::*;

/// A platform point in the spec's workspace box x ∈ [−0.25, 0.25], y ∈ [−0.15, 0.15],
/// z ∈ [−0.43, −0.30] m.
fn workspace_point() -> impl Strategy<Value = Vec3> {
    (-0.25..=0.25f64, -0.15..=0.15f64, -0.43..=-0.30f64).prop_map(|(x, y, z)| Vec3::new(x, y, z))
}

/// Joint rates up to 10 rad/s per joint.
fn joint_rates() -> impl Strategy<Value = Vec3> {
    (-10.0..=10.0f64, -10.0..=10.0f64, -10.0..=10.0f64).prop_map(|(a, b, c)| Vec3::new(a, b, c))
}

fn max_abs(m: &Mat3) -> f64 {
    m.iter().fold(0.0f64, |a, x| a.max(x.abs()))
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    #[test]
    fn fk_of_ik_is_identity(x in workspace_point()) {
        let r = DeltaRobot::default();
        let q = r.ik(&x).unwrap();
        let back = r.fk(&q).unwrap();
        prop_assert!((back - x).amax() < 1e-14, "x {x:?} -> {back:?}");
        let q2 = r.ik(&back).unwrap();
        prop_assert!((q2 - q).amax() < 1e-13, "q {q:?} -> {q2:?}");
    }

    #[test]
    fn jacobian_matches_central_differences_of_fk(x in workspace_point()) {
        let r = DeltaRobot::default();
        let q = r.ik(&x).unwrap();
        let j = r.pose(&q).unwrap().jacobian();
        let h = 1e-6;
        let mut num = Mat3::zeros();
        for c in 0..3 {
            let mut dq = Vec3::zeros();
            dq[c] = h;
            num.set_column(c, &((r.fk(&(q + dq)).unwrap() - r.fk(&(q - dq)).unwrap()) / (2.0 * h)));
        }
        prop_assert!(max_abs(&(num - j)) <= 1e-8 * max_abs(&j));
        // J⁻¹ is its inverse.
        let ji = r.pose(&q).unwrap().jacobian_inv();
        prop_assert!(max_abs(&(ji * j - Mat3::identity())) < 1e-12);
    }

    #[test]
    fn jdot_qdot_matches_second_difference_of_fk(x in workspace_point(), qd in joint_rates()) {
        let r = DeltaRobot::default();
        let q = r.ik(&x).unwrap();
        let pose = r.pose(&q).unwrap();
        let h = 1e-4;
        // d²/ds² FK(q + s q̇) at s = 0 = J̇q̇ (the J q̈ term vanishes for a straight joint path).
        let f = |s: f64| r.fk(&(q + qd * s)).unwrap();
        let num = (f(h) - f(0.0) * 2.0 + f(-h)) / (h * h);
        let exact = pose.jdot_qdot(&qd);
        prop_assert!((num - exact).amax() <= 1e-5 * exact.amax().max(1e-3), "{num:?} vs {exact:?}");
    }

    #[test]
    fn jdot_matches_time_difference_of_j(x in workspace_point(), qd in joint_rates()) {
        let r = DeltaRobot::default();
        let q = r.ik(&x).unwrap();
        let h = 1e-6;
        let j = |s: f64| r.pose(&(q + qd * s)).unwrap().jacobian();
        let num = (j(h) - j(-h)) / (2.0 * h);
        let exact = r.pose(&q).unwrap().jdot(&qd);
        prop_assert!(max_abs(&(num - exact)) <= 1e-7 * max_abs(&exact).max(1e-3));
    }

    #[test]
    fn mdot_minus_2c_is_skew(x in workspace_point(), qd in joint_rates()) {
        let r = DeltaRobot::default();
        let q = r.ik(&x).unwrap();
        let h = 1e-6;
        let m = |s: f64| r.mass(&r.pose(&(q + qd * s)).unwrap());
        let mdot = (m(h) - m(-h)) / (2.0 * h);
        let n = mdot - r.coriolis(&r.pose(&q).unwrap(), &qd) * 2.0;
        prop_assert!(max_abs(&(n + n.transpose())) <= 1e-7 * max_abs(&mdot).max(1e-3));
    }

    #[test]
    fn mass_matrix_is_spd_in_the_box(x in workspace_point()) {
        let r = DeltaRobot::default();
        let pose = r.pose(&r.ik(&x).unwrap()).unwrap();
        let m = r.mass(&pose);
        prop_assert_eq!(m, m.transpose());
        let eig = m.symmetric_eigenvalues();
        // Spec §4.2: eigenvalues in [0.0335, 0.0765] kg m² over the box.
        prop_assert!(eig.min() >= 0.0335 - 1e-4 && eig.max() <= 0.0765 + 1e-4, "{eig:?}");
        prop_assert!(r.margins(&pose).ok());
    }
}

#[test]
fn workspace_box_margins_match_spec() {
    // Spec §3.6 grid 21×13×11: min S/Lb = 0.40, min |det(A/Lb)| = 0.87, cond₂(J) ≤ 1.97.
    let r = DeltaRobot::default();
    let (mut s_min, mut det_min, mut cond_max) = (f64::MAX, f64::MAX, 0.0f64);
    for i in 0..21 {
        for j in 0..13 {
            for k in 0..11 {
                let x = Vec3::new(
                    -0.25 + 0.025 * i as f64,
                    -0.15 + 0.025 * j as f64,
                    -0.43 + 0.013 * k as f64,
                );
                let pose = r.pose(&r.ik(&x).unwrap()).unwrap();
                let m = r.margins(&pose);
                s_min = s_min.min(m.s_over_lb);
                det_min = det_min.min(m.det_a_norm);
                let sv = pose.jacobian().singular_values();
                cond_max = cond_max.max(sv.max() / sv.min());
            }
        }
    }
    assert!((s_min - 0.40).abs() < 0.005, "min S/Lb {s_min}");
    assert!((det_min - 0.87).abs() < 0.005, "min det {det_min}");
    assert!((cond_max - 1.97).abs() < 0.01, "max cond {cond_max}");
}

#[test]
fn unreachable_point_is_an_error_naming_the_point() {
    let r = DeltaRobot::default();
    let err = r.ik(&Vec3::new(0.0, 0.0, -2.0)).unwrap_err();
    let msg = err.to_string();
    assert!(
        msg.contains("-2.000000") && msg.contains("unreachable"),
        "{msg}"
    );
}

#[test]
fn parallel_singularity_is_an_error_not_nan() {
    // All forearms vertical at the centre: q ≈ 120° (docs/delta-robot.md §3.5).
    let r = DeltaRobot::default();
    let q = Vec3::repeat(120f64.to_radians());
    let err = match r.pose(&q) {
        Ok(pose) => r.check_margins(&pose).unwrap_err(),
        Err(e) => e,
    };
    assert!(err.to_string().contains("2.094395"), "{err}");
    // The simulator refuses to start there.
    assert!(PlantSim::new(r, SimConfig::default(), q).is_err());
}

/// Max |E − E0| / max T over 1 s of free motion (τ = 0, d = 0) with h = 30 µs.
fn energy_drift(robot: DeltaRobot, q0: Vec3, qd0: Vec3) -> f64 {
    let cfg = SimConfig {
        check_margins: false,
        ..SimConfig::default()
    };
    let mut sim = PlantSim::new(robot.clone(), cfg, q0).unwrap();
    sim.set_state(q0, qd0);
    let e = |s: &PlantSim| {
        let p = robot.pose(&s.q()).unwrap();
        (robot.energy(&p, &s.qd()), robot.kinetic_energy(&p, &s.qd()))
    };
    let (e0, t0) = e(&sim);
    let (mut max_de, mut max_t) = (0.0f64, t0);
    for _ in 0..3334 {
        sim.step(&Vec3::zeros()).unwrap();
        let (ek, tk) = e(&sim);
        max_de = max_de.max((ek - e0).abs());
        max_t = max_t.max(tk);
    }
    max_de / max_t
}

#[test]
fn energy_e1_gravity_release_from_rest() {
    let q0 = Vec3::new(73.7574, 93.7574, 108.7574).map(f64::to_radians);
    let drift = energy_drift(DeltaRobot::default(), q0, Vec3::zeros());
    assert!(drift < 1e-8, "E1 drift {drift:e}");
}

#[test]
fn energy_e2_no_gravity_initial_velocity() {
    let robot = DeltaRobot::new(deltaloop_model::DeltaParams {
        g: 0.0,
        ..Default::default()
    });
    let q0 = robot.ik(&Vec3::new(0.0, 0.0, -0.37)).unwrap();
    let drift = energy_drift(robot, q0, Vec3::new(1.0, -0.8, 0.6));
    assert!(drift < 1e-8, "E2 drift {drift:e}");
}

#[test]
fn energy_balance_with_constant_torque() {
    // With constant τ and d = 0, E − τᵀq is conserved (docs/delta-robot.md §5).
    let robot = DeltaRobot::default();
    let q0 = robot.ik(&Vec3::new(0.05, -0.03, -0.40)).unwrap();
    let pose = robot.pose(&q0).unwrap();
    let tau = robot.gravity(&pose) + Vec3::new(0.3, -0.2, 0.1);
    let mut sim = PlantSim::new(robot.clone(), SimConfig::default(), q0).unwrap();
    let h = |s: &PlantSim| robot.energy(&robot.pose(&s.q()).unwrap(), &s.qd()) - tau.dot(&s.q());
    let h0 = h(&sim);
    for _ in 0..1000 {
        sim.step(&tau).unwrap();
    }
    assert!((h(&sim) - h0).abs() < 1e-10, "{} vs {}", h(&sim), h0);
}
