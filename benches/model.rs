//! Criterion benches of the model functions, one plant tick, and one controller step per law.
//! `cargo bench --bench model`. The plant tick (40 dynamics evaluations) is the real-time budget's
//! main consumer; `forward dynamics` vs `M, C q̇, G (matrix form) + nalgebra Cholesky` is the
//! same-run baseline for the hand-written hot path.

use criterion::{Criterion, criterion_group, criterion_main};
use deltaloop_config::{ControllerParams, Law, Preset};
use deltaloop_law::{
    Controller, Delay, DelayEstimate, InertiaEstimate, Measurement, Predictor, Reference,
};
use deltaloop_model::{DeltaRobot, Plant, SimConfig, Vec3};
use std::hint::black_box;

fn model(c: &mut Criterion) {
    let robot = DeltaRobot::default();
    let x = Vec3::new(0.05, -0.03, -0.40);
    let q = robot.ik(&x).unwrap();
    let qd = Vec3::new(1.0, -0.5, 0.25);
    let pose = robot.pose(&q).unwrap();
    let tau = robot.gravity(&pose) + Vec3::new(0.3, -0.2, 0.1);
    let mut g = c.benchmark_group("model");
    g.bench_function("ik", |b| b.iter(|| robot.ik(black_box(&x))));
    g.bench_function("fk", |b| b.iter(|| robot.fk(black_box(&q))));
    g.bench_function("pose (fk + A^-1 + beta)", |b| {
        b.iter(|| robot.pose(black_box(&q)))
    });
    g.bench_function("jacobian", |b| b.iter(|| black_box(&pose).jacobian()));
    g.bench_function("jdot_qdot", |b| {
        b.iter(|| black_box(&pose).jdot_qdot(black_box(&qd)))
    });
    g.bench_function("mass", |b| b.iter(|| robot.mass(black_box(&pose))));
    g.bench_function("gravity", |b| b.iter(|| robot.gravity(black_box(&pose))));
    g.bench_function("friction", |b| b.iter(|| robot.friction(black_box(&qd))));
    g.bench_function("forward dynamics (hot path)", |b| {
        b.iter(|| robot.forward_dynamics(black_box(&pose), black_box(&qd), black_box(&tau)))
    });
    g.bench_function("baseline: M, C qdot, G + nalgebra Cholesky", |b| {
        b.iter(|| {
            let p = black_box(&pose);
            let m = robot.mass(p);
            let rhs = black_box(tau) - robot.coriolis_qdot(p, &qd) - robot.gravity(p);
            m.cholesky().unwrap().solve(&rhs)
        })
    });
    g.finish();

    let mut g = c.benchmark_group("plant");
    for friction in [false, true] {
        let cfg = SimConfig {
            friction,
            ..SimConfig::default()
        };
        let mut plant = Plant::new(robot.clone(), cfg, 100.0, 0, q).unwrap();
        let name = format!("tick: 10 RK4 substeps (friction {friction})");
        g.bench_function(name, |b| {
            b.iter_batched_ref(
                || plant.clone(),
                |p| p.advance(Some(black_box(tau))),
                criterion::BatchSize::SmallInput,
            )
        });
        plant.advance(Some(tau)).unwrap();
    }
    g.finish();
}

fn controller(c: &mut Criterion) {
    let mut g = c.benchmark_group("controller step");
    let m = Measurement {
        q: Vec3::new(0.1, 0.2, 0.3),
        qd: Vec3::new(1.0, -0.5, 0.2),
        tau_applied: Vec3::new(-1.3, -1.2, -1.1),
    };
    let r = Reference {
        q: Vec3::new(0.1001, 0.2, 0.2999),
        qd: Vec3::new(1.01, -0.5, 0.2),
        qdd: Vec3::new(3.0, -2.0, 1.0),
    };
    let params = ControllerParams::preset(Preset::Matched);
    for &law in Law::ALL {
        let mut ctrl = Controller::new(law, params, 3e-4, 1);
        g.bench_function(law.name(), |b| {
            b.iter(|| ctrl.step(black_box(&m), black_box(&r)))
        });
    }
    // Compensated at eight ticks plus 100 µs of delay: nine torques in flight per step, and
    // the inertia estimate's update (docs/controllers.md, "Delay compensation").
    for law in [Law::Tdc, Law::TdeIs, Law::TdcIsSta, Law::TdcIsIsta] {
        let predictor = Predictor::new(
            Delay::from_ns(8 * 300_000 + 100_000, 300_000),
            3e-4,
            100.0,
            InertiaEstimate::for_m_bar(params.m_bar),
        );
        let mut ctrl = Controller::new(law, params, 3e-4, 1).with_predictor(predictor);
        g.bench_function(
            format!("{}, compensated, d = 8 + 100 us", law.name()),
            |b| b.iter(|| ctrl.step(black_box(&m), black_box(&r))),
        );
    }
    // What measuring the delay adds to a compensated step (docs/controllers.md, "D in
    // realtime"): one report learned from (a least-squares fit per candidate m and the median of
    // the last 31 fits) and one command recorded, commands that change every tick.
    let mut est = DelayEstimate::new(Delay::from_ns(8 * 300_000 + 100_000, 300_000), 3e-4, 100.0);
    let mut k = 0u64;
    g.bench_function("delay measured, d = 8 + 100 us", |b| {
        b.iter(|| {
            k += 1;
            let c = Vec3::repeat((k % 7) as f64 * 0.1);
            est.observe(black_box(k), black_box(c * 0.7));
            est.sent(k, black_box(c));
        })
    });
    g.finish();
}

criterion_group!(benches, model, controller);
criterion_main!(benches);
