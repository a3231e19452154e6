//! The control laws (docs/controllers.md, "The laws"). One [`Controller`] runs one law; call
//! [`Controller::step`] once per tick k with that tick's measurement and reference.

use crate::predict::Predictor;
use crate::{ControllerParams, Law, TdeHistory, Vec3, VelocitySource, sat, sgn};

/// What the controller measures at tick k.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Measurement {
    /// Joint angles q_k, rad.
    pub q: Vec3,
    /// Joint rates q̇_k, rad/s.
    pub qd: Vec3,
    /// Torque the drives applied over [t_{k−1}, t_k) (τᵃ_k), N m. At k = 0, the holding torque.
    pub tau_applied: Vec3,
}

/// The joint reference at tick k.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Reference {
    /// Desired joint angles q_d,k, rad.
    pub q: Vec3,
    /// Desired joint rates q̇_d,k, rad/s.
    pub qd: Vec3,
    /// Desired joint accelerations q̈_d,k, rad/s².
    pub qdd: Vec3,
}

/// What the controller sends at tick k.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Output {
    /// Commanded torque τ_k (unclamped; the drives clamp), N m.
    pub tau: Vec3,
    /// Sliding variable s_k = ė + K_d e + K_p ∫e, rad/s.
    pub s: Vec3,
    /// TDE of the lumped unknown term N̂_k, rad/s² (computed for every law; PID does not use it).
    pub n_hat: Vec3,
    /// Robust term u_k, rad/s² (0 for `tdc` and `pid`).
    pub u: Vec3,
}

/// One control law with its state. Allocates only in [`Controller::new`].
#[derive(Clone, Debug)]
pub struct Controller {
    law: Law,
    p: ControllerParams,
    ts: f64,
    tde: TdeHistory,
    started: bool,
    /// Where q̇ and the TDE accelerations come from.
    velocity: VelocitySource,
    /// q̇_{k−1}, rad/s (the rate this controller used at the previous tick).
    qd_prev: Vec3,
    /// Encoder-difference source: q_{k−1}, q_{k−2} (rad) and τᵃ_{k−1} (N m).
    q_prev: [Vec3; 2],
    tau_prev: Vec3,
    /// ∫e, E_{k−1}, rad s.
    e_int: Vec3,
    /// Super-twisting integral state v_k, rad/s².
    v: Vec3,
    /// PID integral state z_{k−1}, N m.
    z: Vec3,
    /// Delay compensation: the law acts on the state predicted for when its torque acts.
    predictor: Option<Predictor>,
}

impl Controller {
    /// A controller for `law` with constants `p`, control period `ts` (s) and TDE delay `ell` (≥ 1
    /// ticks). The start-up history comes from the first measurement (τᵃ_0), not from a model.
    pub fn new(law: Law, p: ControllerParams, ts: f64, ell: usize) -> Self {
        Self {
            law,
            p,
            ts,
            tde: TdeHistory::new(ell.max(1), Vec3::zeros()),
            started: false,
            velocity: VelocitySource::Measured,
            qd_prev: Vec3::zeros(),
            q_prev: [Vec3::zeros(); 2],
            tau_prev: Vec3::zeros(),
            e_int: Vec3::zeros(),
            v: Vec3::zeros(),
            z: Vec3::zeros(),
            predictor: None,
        }
    }

    /// Compensates the delay until its torque acts with `p` (docs/controllers.md, "Delay
    /// compensation"): each tick the law runs on the state `p` predicts for that time, and the
    /// caller passes the reference at that time. `pid` has no TDE model to predict with and is
    /// left as it is.
    pub fn with_predictor(mut self, p: Predictor) -> Self {
        if self.law.uses_tde() {
            self.predictor = Some(p);
        }
        self
    }

    /// Predicts over `d` from the next step on (a delay measured as the loop runs); nothing
    /// without compensation.
    pub fn set_delay(&mut self, d: crate::Delay) {
        if let Some(p) = &mut self.predictor {
            p.set_delay(d);
        }
    }

    /// The delay compensation in use, if any.
    pub fn predictor(&self) -> Option<&Predictor> {
        self.predictor.as_ref()
    }

    /// Takes q̇ and the TDE accelerations from `v` (default: the measured q̇).
    pub fn with_velocity(mut self, v: VelocitySource) -> Self {
        self.velocity = v;
        self
    }

    /// The law this controller runs.
    pub fn law(&self) -> Law {
        self.law
    }

    /// The control period Ts, s.
    pub fn ts(&self) -> f64 {
        self.ts
    }

    /// The constants in use.
    pub fn params(&self) -> &ControllerParams {
        &self.p
    }

    /// Seeds the state directly (for checks against hand-computed steps): previous rate q̇_{k−1}
    /// (rad/s), E_{k−1} (rad s), v_k (rad/s²). Marks the controller as started.
    pub fn seed(&mut self, qd_prev: Vec3, e_int_prev: Vec3, v: Vec3, tau_hist: Vec3) {
        self.started = true;
        self.qd_prev = qd_prev;
        self.e_int = e_int_prev;
        self.v = v;
        self.z = tau_hist;
        self.tde.reset(tau_hist);
    }

    /// Tick k: updates E_k (and z_k), computes τ_k, then v_{k+1}.
    pub fn step(&mut self, m: &Measurement, r: &Reference) -> Output {
        if !self.started {
            // Before tick 0 the robot rested at q_0 under τᵃ_0: a_j = 0, τᵃ_j = τᵃ_0, z_{−1} = τᵃ_0;
            // for the encoder source also q_{−1} = q_{−2} = q_0 and τᵃ_{−1} = τᵃ_0.
            self.started = true;
            self.tde.reset(m.tau_applied);
            self.qd_prev = m.qd;
            self.q_prev = [m.q; 2];
            self.tau_prev = m.tau_applied;
            self.z = m.tau_applied;
            if let Some(p) = &mut self.predictor {
                p.reset(m.tau_applied);
            }
        }
        let ts = self.ts;
        let p = &self.p;
        let (qd, accel_prev, tau_pair) = match self.velocity {
            // a_{k−1} = (q̇_k − q̇_{k−1})/Ts, paired with τᵃ_k.
            VelocitySource::Measured => (m.qd, (m.qd - self.qd_prev) / ts, m.tau_applied),
            // q̇_k = (q_k − q_{k−1})/Ts; a_{k−1} = (q_k − 2q_{k−1} + q_{k−2})/Ts², paired with
            // the mean of τᵃ_{k−1} and τᵃ_k (the two intervals the second difference spans).
            VelocitySource::EncoderDifference => {
                let [q1, q2] = self.q_prev;
                let qd = (m.q - q1) / ts;
                let a = (m.q - q1 * 2.0 + q2) / (ts * ts);
                let pair = (self.tau_prev + m.tau_applied) / 2.0;
                self.q_prev = [m.q, q1];
                self.tau_prev = m.tau_applied;
                (qd, a, pair)
            }
        };
        self.qd_prev = qd;
        let (a_lag, tau_lag) = self.tde.push(accel_prev, tau_pair);
        // The state the torque will meet: measured, or predicted over the torques in flight.
        let (q, qd) = match &mut self.predictor {
            Some(p) => p.predict(m.q, qd, accel_prev, tau_pair),
            None => (m.q, qd),
        };

        let e = r.q - q;
        let ed = r.qd - qd;
        self.e_int += e * ts;
        let s = ed + e * p.kd + self.e_int * p.kp;
        let n_hat = a_lag - tau_lag / p.m_bar;

        // The switching term u_k, one arm per law: a new law must say what it adds here.
        let u = match self.law {
            Law::Tdc | Law::Pid => Vec3::zeros(),
            Law::TdeIs if p.phi > 0.0 => s.map(|si| p.ks * sat(si / p.phi)),
            Law::TdeIs => s.map(|si| p.ks * sgn(si)),
            Law::TdcIsSta => {
                // u_k from v_k; the state moves on to v_{k+1} (used from tick k + 1).
                let (k1, k2, v) = (p.k1, p.k2, &mut self.v);
                Vec3::from_fn(|i, _| {
                    let (ui, vi) = crate::sta::explicit(s[i], v[i], k1, k2, ts);
                    v[i] = vi;
                    ui
                })
            }
            Law::TdcIsIsta => {
                let (k1, k2, v) = (p.k1, p.k2, &mut self.v);
                Vec3::from_fn(|i, _| {
                    let (ui, vi) = crate::sta::implicit(s[i], v[i], k1, k2, ts);
                    v[i] = vi;
                    ui
                })
            }
        };
        let tau = match self.law {
            Law::Pid => {
                self.z += e * (p.pid_i * ts);
                e * p.pid_p + self.z + ed * p.pid_d
            }
            // The expanded form of the spec: τ = τᵃ_{k−ℓ+1} − M̄ a_{k−ℓ} + M̄ (q̈_d + K_d ė + K_p e + u).
            Law::Tdc | Law::TdeIs | Law::TdcIsSta | Law::TdcIsIsta => {
                tau_lag - a_lag * p.m_bar + (r.qdd + ed * p.kd + e * p.kp + u) * p.m_bar
            }
        };
        if let Some(p) = &mut self.predictor {
            p.sent(tau);
        }
        Output { tau, s, n_hat, u }
    }

    /// The super-twisting state v_k, rad/s² (zero for laws without a super-twisting term).
    pub fn sta_state(&self) -> Vec3 {
        self.v
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{ControllerParams, Preset};

    fn paper() -> ControllerParams {
        ControllerParams::preset(Preset::Paper)
    }

    /// The one-step check of the docs/controllers.md, on joint 1 (joints 2 and 3 carry the same data).
    #[test]
    fn one_step_check_from_spec() {
        let mut c = Controller::new(Law::TdcIsSta, paper(), 3e-4, 1);
        c.seed(
            Vec3::repeat(1.185),
            Vec3::repeat(1e-6),
            Vec3::repeat(0.02),
            Vec3::repeat(1.4),
        );
        let m = Measurement {
            q: Vec3::repeat(0.4999),
            qd: Vec3::repeat(1.19),
            tau_applied: Vec3::repeat(1.4),
        };
        let r = Reference {
            q: Vec3::repeat(0.5),
            qd: Vec3::repeat(1.2),
            qdd: Vec3::repeat(-3.0),
        };
        let out = c.step(&m, &r);
        let rel = |a: f64, b: f64| ((a - b) / b).abs();
        assert!(rel(out.s[0], 0.191854) < 1e-9, "s = {}", out.s[0]);
        assert!(rel(out.n_hat[0], -4650.0) < 1e-9, "N̂ = {}", out.n_hat[0]);
        assert!(rel(out.u[0], 306.627990763) < 1e-9, "u = {}", out.u[0]);
        assert!(
            rel(out.tau[0], 1.491542397229) < 1e-11,
            "tau = {}",
            out.tau[0]
        );
        assert!(
            rel(c.sta_state()[0], 0.05) < 1e-12,
            "v = {}",
            c.sta_state()[0]
        );
        assert_eq!(out.tau[0], out.tau[2]);
    }

    #[test]
    fn sgn_and_sat_are_odd_with_sgn_zero() {
        assert_eq!(sgn(0.0), 0.0);
        assert_eq!(sgn(-0.0), 0.0);
        for x in [1e-300, 0.3, 1.0, 2.5, 1e9, f64::INFINITY] {
            assert_eq!(sgn(-x), -sgn(x));
            assert_eq!(sat(-x), -sat(x));
        }
        assert_eq!(sat(0.5), 0.5);
        assert_eq!(sat(7.0), 1.0);
    }

    #[test]
    fn s0_is_zero_and_start_is_bumpless_for_every_law() {
        // At rest on the reference, every law's first torque is the holding torque τᵃ_0 and s₀ = 0.
        let tau0 = Vec3::new(-1.3, -1.2, -1.1);
        let m = Measurement {
            q: Vec3::new(0.1, 0.2, 0.3),
            qd: Vec3::zeros(),
            tau_applied: tau0,
        };
        let r = Reference {
            q: m.q,
            qd: Vec3::zeros(),
            qdd: Vec3::zeros(),
        };
        for preset in [Preset::Matched, Preset::Paper] {
            for &law in Law::ALL {
                let mut c = Controller::new(law, ControllerParams::preset(preset), 3e-4, 3);
                let out = c.step(&m, &r);
                assert_eq!(out.s, Vec3::zeros(), "{law}");
                assert_eq!(out.tau, tau0, "{law} {preset:?}");
            }
        }
    }

    #[test]
    fn tde_uses_data_ell_ticks_old() {
        // Feed a known rate ramp and check N̂_k = a_{k−ℓ} − τᵃ_{k−ℓ+1}/M̄ for ℓ = 3.
        let p = ControllerParams::preset(Preset::Matched);
        let ts = 3e-4;
        let mut c = Controller::new(Law::Tdc, p, ts, 3);
        let r = Reference::default();
        let qd = |k: usize| Vec3::repeat((k * k) as f64 * 0.01);
        let tau = |k: usize| Vec3::repeat(k as f64);
        for k in 0..8 {
            let out = c.step(
                &Measurement {
                    q: Vec3::zeros(),
                    qd: qd(k),
                    tau_applied: tau(k),
                },
                &r,
            );
            let j = k as i64 - 3; // a_{k−ℓ}
            let a = if j < 0 {
                0.0
            } else {
                (qd(j as usize + 1)[0] - qd(j as usize)[0]) / ts
            };
            let t = if j < 0 {
                tau(0)[0]
            } else {
                tau((j + 1) as usize)[0]
            };
            assert!(
                (out.n_hat[0] - (a - t / p.m_bar)).abs() < 1e-9,
                "k={k}: {} vs {}",
                out.n_hat[0],
                a - t / p.m_bar
            );
        }
    }

    #[test]
    fn encoder_source_uses_second_difference_and_mean_torque() {
        // q_k = c k² (constant acceleration 2c/Ts²): the second difference is exact from k = 2.
        let p = ControllerParams::preset(Preset::Matched);
        let ts = 3e-4;
        let mut c =
            Controller::new(Law::Tdc, p, ts, 1).with_velocity(VelocitySource::EncoderDifference);
        let coef = 1e-6;
        let q = |k: usize| Vec3::repeat(coef * (k * k) as f64);
        let tau = |k: usize| Vec3::repeat(1.0 + k as f64);
        for k in 0..6 {
            let out = c.step(
                &Measurement {
                    q: q(k),
                    qd: Vec3::repeat(99.0),
                    tau_applied: tau(k),
                },
                &Reference::default(),
            );
            // ℓ = 1: N̂_k = a_{k−1} − M̄⁻¹ (τᵃ_{k−1} + τᵃ_k)/2, with q_{−1} = q_{−2} = q_0, τᵃ_{−1} = τᵃ_0.
            let qm = |j: i64| if j < 0 { q(0)[0] } else { q(j as usize)[0] };
            let a = (qm(k as i64) - 2.0 * qm(k as i64 - 1) + qm(k as i64 - 2)) / (ts * ts);
            let pair = (tau(k.saturating_sub(1))[0] + tau(k)[0]) / 2.0;
            assert!((out.n_hat[0] - (a - pair / p.m_bar)).abs() < 1e-9, "k={k}");
            // The measured q̇ (99) is ignored: s uses (q_k − q_{k−1})/Ts.
            let qd = (qm(k as i64) - qm(k as i64 - 1)) / ts;
            assert!(
                (out.s[0] - (-qd - p.kd * q(k)[0] + 0.0)).abs() < 1e-3,
                "k={k}: s {}",
                out.s[0]
            );
        }
    }

    #[test]
    fn pid_integrates_from_the_holding_torque() {
        let p = ControllerParams::preset(Preset::Matched);
        let mut c = Controller::new(Law::Pid, p, 3e-4, 1);
        let tau0 = Vec3::new(1.0, 2.0, 3.0);
        let r = Reference {
            q: Vec3::repeat(0.01),
            ..Reference::default()
        };
        let out = c.step(
            &Measurement {
                tau_applied: tau0,
                ..Measurement::default()
            },
            &r,
        );
        // τ = P e + (τᵃ_0 + I Ts e) + D ė
        let want = Vec3::repeat(0.01 * 1800.0) + tau0 + Vec3::repeat(6.7e4 * 3e-4 * 0.01);
        assert!((out.tau - want).amax() < 1e-12, "{:?}", out.tau);
    }

    #[test]
    fn tde_is_with_zero_phi_is_sgn() {
        let mut p = ControllerParams::preset(Preset::Matched);
        p.phi = 0.0;
        let mut c = Controller::new(Law::TdeIs, p, 3e-4, 1);
        let r = Reference {
            q: Vec3::new(1e-9, -1e-9, 0.0),
            ..Reference::default()
        };
        let out = c.step(&Measurement::default(), &r);
        assert_eq!(out.u, Vec3::new(p.ks, -p.ks, 0.0));
    }
}
