use super::*;

const TS: f64 = 3e-4;
const TS_NS: u64 = 300_000;

/// A double integrator per joint, M q̈ = τ(t) + N (N constant), whose drives apply command j
/// (clamped to ±τ_max) from t_j + D on, and `tau0` before the first command: exact states.
struct DoubleIntegrator {
    m: Vec3,
    n: Vec3,
    tau0: Vec3,
    tau_max: f64,
    delay_s: f64,
    cmds: Vec<Vec3>,
}

impl DoubleIntegrator {
    /// The torque acting at time t (s).
    fn torque_at(&self, t: f64) -> Vec3 {
        let due = |j: usize| j as f64 * TS + self.delay_s;
        (0..self.cmds.len())
            .rev()
            .find(|&j| due(j) <= t + 1e-15)
            .map_or(self.tau0, |j| {
                self.cmds[j].map(|x| x.clamp(-self.tau_max, self.tau_max))
            })
    }

    /// Every time in (0, t) the acting torque may change: the ticks and the commands' due times.
    fn breaks(&self, t: f64) -> Vec<f64> {
        let mut b: Vec<f64> = (1..)
            .map(|j| j as f64 * TS)
            .take_while(|&x| x < t)
            .chain((0..self.cmds.len()).map(|j| j as f64 * TS + self.delay_s))
            .filter(|&x| x > 0.0 && x < t)
            .collect();
        b.sort_by(f64::total_cmp);
        b.push(t);
        b
    }

    /// (q, q̇) at time t from rest at 0, exactly (constant acceleration between breaks).
    fn state_at(&self, t: f64) -> (Vec3, Vec3) {
        let (mut q, mut qd, mut at) = (Vec3::zeros(), Vec3::zeros(), 0.0);
        for b in self.breaks(t) {
            let h = b - at;
            let acc = (self.torque_at(at) + self.n).component_div(&self.m);
            q += qd * h + acc * (0.5 * h * h);
            qd += acc * h;
            at = b;
        }
        (q, qd)
    }

    /// The mean torque over [t_{k−1}, t_k) (τᵃ_k; `tau0` at k = 0).
    fn applied(&self, k: usize) -> Vec3 {
        if k == 0 {
            return self.tau0;
        }
        let (t0, t1) = ((k - 1) as f64 * TS, k as f64 * TS);
        let mut sum = Vec3::zeros();
        let mut at = t0;
        for b in self.breaks(t1).into_iter().filter(|&b| b > t0) {
            sum += self.torque_at(at) * (b - at);
            at = b;
        }
        sum / TS
    }
}

/// With the exact inertia, the prediction over the commands in flight is the double integrator's
/// state at t_k + D, for whole-tick, sub-tick and mixed delays, with commands the drives clamp.
#[test]
fn prediction_with_the_exact_inertia_is_the_delayed_state() {
    let m = Vec3::new(0.05, 0.08, 0.12);
    let n = Vec3::new(-2.0, 0.5, 1.0);
    for delay_ns in [300_000, 600_000, 150_000, 450_000, 2_400_000u64] {
        let delay_s = delay_ns as f64 / 1e9;
        let mut plant = DoubleIntegrator {
            m,
            n,
            tau0: -n,
            tau_max: 3.0,
            delay_s,
            cmds: Vec::new(),
        };
        let mut p = Predictor::new(
            Delay::from_ns(delay_ns, TS_NS),
            TS,
            plant.tau_max,
            InertiaEstimate::fixed(m),
        );
        p.reset(plant.tau0);
        let mut qd_prev = Vec3::zeros();
        for k in 0..40 {
            let t = k as f64 * TS;
            let (q, qd) = plant.state_at(t);
            let accel = if k == 0 {
                Vec3::zeros()
            } else {
                (qd - qd_prev) / TS
            };
            qd_prev = qd;
            let (qp, qdp) = p.predict(q, qd, accel, plant.applied(k));
            let (qx, qdx) = plant.state_at(t + delay_s);
            assert!(
                (qp - qx).amax() <= 1e-12 * (1.0 + qx.amax()),
                "D = {delay_s}, k = {k}: q {qp} vs {qx}"
            );
            assert!(
                (qdp - qdx).amax() <= 1e-9 * (1.0 + qdx.amax()),
                "D = {delay_s}, k = {k}: q̇ {qdp} vs {qdx}"
            );
            // Commands that swing past the limit now and then.
            let x = k as f64;
            let cmd = Vec3::new(4.0 * (0.7 * x).sin(), 2.0 * (0.3 * x).cos(), -1.0 + 0.1 * x);
            plant.cmds.push(cmd);
            p.sent(cmd);
        }
    }
}

/// No delay, nothing in flight: the prediction is the measurement.
#[test]
fn no_delay_predicts_the_measurement() {
    let mut p = Predictor::new(
        Delay::from_ns(0, TS_NS),
        TS,
        10.0,
        InertiaEstimate::for_m_bar(0.03),
    );
    p.reset(Vec3::repeat(1.0));
    let (q, qd) = (Vec3::new(0.1, 0.2, 0.3), Vec3::new(-1.0, 0.0, 1.0));
    assert_eq!(p.predict(q, qd, Vec3::repeat(5.0), Vec3::zeros()), (q, qd));
}

#[test]
fn a_delay_splits_into_whole_ticks_and_a_sub_tick_part() {
    assert_eq!(
        Delay::from_ns(TS_NS, TS_NS),
        Delay {
            whole: 1,
            frac: 0.0
        }
    );
    assert_eq!(Delay::from_ns(8 * TS_NS, TS_NS).in_flight(), 8);
    assert_eq!(Delay::from_ns(0, TS_NS).in_flight(), 0);
    let d = Delay::from_ns(150_000, TS_NS);
    assert_eq!((d.whole, d.in_flight(), d.frac), (0, 1, 150e-6));
    let d = Delay::from_ns(450_000, TS_NS);
    assert_eq!((d.whole, d.in_flight(), d.frac), (1, 2, 150e-6));
}

/// A quadratic reference is stepped exactly to any sub-tick time; δ = 0 is row j itself.
#[test]
fn the_reference_ahead_of_a_row_is_exact_for_a_quadratic() {
    let at = |t: f64| Reference {
        q: Vec3::new(0.1 + 2.0 * t + 3.0 * t * t, -t, 0.5),
        qd: Vec3::new(2.0 + 6.0 * t, -1.0, 0.0),
        qdd: Vec3::new(6.0, 0.0, 0.0),
    };
    let (row, next) = (at(1.0), at(1.0 + TS));
    assert_eq!(reference_ahead(&row, &next, 0.0, TS), row);
    let r = reference_ahead(&row, &next, 150e-6, TS);
    let x = at(1.0 + 150e-6);
    assert!((r.q - x.q).amax() < 1e-14 && (r.qd - x.qd).amax() < 1e-12);
    assert_eq!(r.qdd, x.qdd);
}

/// From a prior 2× off, the estimate finds a robot's inertia from its measured accelerations
/// and applied torques (a slow motion with a fast ripple, as a switching law's torque has),
/// under a slowly drifting unknown term, and stays within its bounds.
#[test]
fn the_inertia_estimate_converges_from_its_prior_and_keeps_its_bounds() {
    let m_true = Vec3::new(0.045, 0.06, 0.07);
    let mut est = InertiaEstimate::for_m_bar(0.03);
    assert_eq!(est.m_hat(), Vec3::repeat(0.06));
    for k in 0..20_000 {
        let t = k as f64 * TS;
        let ripple = Vec3::new((3000.0 * t).sin(), (2300.0 * t).cos(), (1700.0 * t).sin()) * 0.2;
        let tau = Vec3::new((40.0 * t).sin(), (23.0 * t).cos(), (31.0 * t).sin() * 2.0) + ripple;
        let drift = Vec3::repeat(0.5 * (0.7 * t).sin());
        est.learn((tau + drift).component_div(&m_true), tau);
    }
    let rel = (est.m_hat() - m_true).component_div(&m_true).amax();
    assert!(rel < 0.01, "M̂ {} vs {m_true}", est.m_hat());

    // A torque that never changes teaches nothing; accelerations beyond any inertia's bounds
    // leave M̂ at a bound.
    let mut est = InertiaEstimate::for_m_bar(0.03);
    for _ in 0..100 {
        est.learn(Vec3::repeat(3.0), Vec3::repeat(1.0));
    }
    assert_eq!(est.m_hat(), Vec3::repeat(0.06));
    for k in 0..1000 {
        let tau = Vec3::repeat(if k % 2 == 0 { 1.0 } else { -1.0 });
        est.learn(tau * 1e6, tau);
    }
    let (lo, _) = BOUNDS_OVER_M_BAR;
    assert!(
        (est.m_hat() - Vec3::repeat(lo * 0.03)).amax() < 1e-12,
        "{}",
        est.m_hat()
    );
}

/// The drives' report τᵃ_k over [t_{k−1}, t_k) when the reply to tick j acts from t_j + D:
/// the commands of that interval, clamped, weighted by how long each acted.
fn applied(cmds: &[Vec3], k: usize, d: f64, tau_max: f64) -> Vec3 {
    // Command j acts over [t_j + D, t_{j+1} + D); before tick 0, c_0's predecessor held 0.
    let clamp = |v: Vec3| v.map(|t| t.clamp(-tau_max, tau_max));
    let (t0, t1) = ((k as f64 - 1.0) * TS, k as f64 * TS);
    let mut sum = Vec3::zeros();
    for (j, c) in cmds.iter().enumerate() {
        let (a, b) = (j as f64 * TS + d, (j + 1) as f64 * TS + d);
        let overlap = (b.min(t1) - a.max(t0)).max(0.0);
        sum += clamp(*c) * overlap;
    }
    sum / TS
}

/// The delay measured from the drives' reports is the delay the commands met, for whole,
/// sub-tick and mixed delays up to a tick past D₀, with clamped commands and with ticks the
/// controller skipped (no command of its own for them); with no tick to learn from it stays D₀.
#[test]
fn the_measured_delay_is_the_one_the_commands_met() {
    let tau_max = 1.5;
    let cmds: Vec<Vec3> = (0..400)
        .map(|j| {
            let t = j as f64 * TS;
            Vec3::new(
                (300.0 * t).sin() * 2.0,
                (170.0 * t).cos(),
                0.3 * (90.0 * t).sin(),
            )
        })
        .collect();
    for (base_us, true_us) in [
        (0.0, 40.0),
        (0.0, 0.0),
        (150.0, 270.0),
        (300.0, 300.0),
        (450.0, 700.0),
    ] {
        let base = Delay::from_s(base_us * 1e-6, TS);
        let mut est = DelayEstimate::new(base, TS, tau_max);
        assert!((est.delay().seconds(TS) - base_us * 1e-6).abs() < 1e-12);
        let d = true_us * 1e-6;
        for k in 0..cmds.len() {
            // Every seventh tick the controller skipped (sent nothing for it).
            if k >= 3 {
                est.observe(k as u64, applied(&cmds[..k], k, d, tau_max));
            }
            if k % 7 != 3 {
                est.sent(k as u64, cmds[k]);
            }
        }
        let got = est.delay().seconds(TS);
        assert!(
            (got - d).abs() < 1e-9,
            "D₀ {base_us} µs, true {true_us} µs: measured {} µs",
            got * 1e6
        );
        assert!(est.max().seconds(TS) >= d);
    }
    // Constant commands say nothing: D₀ stays.
    let mut est = DelayEstimate::new(Delay::from_s(150e-6, TS), TS, tau_max);
    for k in 0..100u64 {
        est.observe(k, Vec3::repeat(0.5));
        est.sent(k, Vec3::repeat(0.5));
    }
    assert!((est.delay().seconds(TS) - 150e-6).abs() < 1e-12);
}

/// A predictor whose delay is set each tick walks the commands of that delay: set to the delay
/// it was built for, it predicts what it predicted before; room is made up front, and a delay
/// past the room is cut to it.
#[test]
fn a_predictor_set_to_another_delay_walks_its_commands() {
    let make = |d: Delay| Predictor::new(d, TS, 100.0, InertiaEstimate::fixed(Vec3::repeat(0.05)));
    let d1 = Delay::from_s(450e-6, TS);
    let mut fixed = make(d1);
    let mut moving = make(Delay::from_s(0.0, TS)).with_room_for(Delay::from_s(600e-6, TS));
    moving.set_delay(d1);
    for p in [&mut fixed, &mut moving] {
        p.reset(Vec3::repeat(0.1));
        for j in 0..5 {
            p.sent(Vec3::repeat(j as f64));
        }
    }
    let args = (
        Vec3::repeat(0.2),
        Vec3::repeat(0.01),
        Vec3::repeat(0.3),
        Vec3::repeat(0.1),
    );
    assert_eq!(
        fixed.predict(args.0, args.1, args.2, args.3),
        moving.predict(args.0, args.1, args.2, args.3)
    );
    moving.set_delay(Delay::from_s(10.0 * TS, TS));
    assert_eq!(moving.delay().in_flight(), 2, "cut to the room made");
}
