//! Why the paper's literal M̄ misbehaves on this plant (docs/controllers.md, "The laws", presets):
//! with M̄ ≪ M the TDC core acts like a lightly damped PID, P = M̄K_d/Ts, I = M̄K_p/Ts, D = M̄/Ts,
//! whose TDE lags Ts·M/M̄ behind the plant. Pure numbers from the model along the reference.

use crate::reference::JointReference;
use deltaloop_law::ControllerParams;
use deltaloop_model::DeltaRobot;
use serde::Serialize;

/// The gain/plant mismatch of a preset on the reference path.
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct Mismatch {
    /// M̄, kg m².
    pub m_bar: f64,
    /// Smallest and largest eigenvalue of M(q_d) along the path, kg m².
    pub lambda_min: f64,
    pub lambda_max: f64,
    /// Mean diagonal entry of M(q_d) along the path (mean joint inertia), kg m².
    pub joint_inertia_mean: f64,
    /// TDE lag Ts·λ/M̄ at the extreme eigenvalues, s.
    pub tde_lag_min_s: f64,
    pub tde_lag_max_s: f64,
    /// Equivalent PID of the TDC core: P (N m/rad), I (N m/(rad s)), D (N m s/rad).
    pub equiv_p: f64,
    pub equiv_i: f64,
    pub equiv_d: f64,
    /// Natural frequency √(P/m)/(2π) of that PID on the mean joint inertia, Hz.
    pub equiv_freq_hz: f64,
    /// Its damping ratio D/(2√(P m)).
    pub equiv_zeta: f64,
}

/// Evaluates the mismatch of constants `p` along `reference`.
pub fn mismatch(robot: &DeltaRobot, reference: &JointReference, p: &ControllerParams) -> Mismatch {
    let ts = reference.ts;
    let (mut lo, mut hi, mut diag_sum, mut count) = (f64::MAX, 0.0f64, 0.0, 0usize);
    // The rows of the hold are all alike: evaluate the mass matrix once per distinct row.
    let mut held: Option<(f64, f64, f64)> = None;
    for k in 0..=reference.n {
        let (min, max, diag) = match held {
            Some(h) if reference.in_hold(k) => h,
            _ => {
                let row = reference.row(k);
                let m = robot.mass(&robot.pose_at(&row.joint.q, &row.task.x));
                let eig = m.symmetric_eigenvalues();
                (eig.min(), eig.max(), m.diagonal().sum())
            }
        };
        if reference.in_hold(k) {
            held = Some((min, max, diag));
        }
        lo = lo.min(min);
        hi = hi.max(max);
        diag_sum += diag;
        count += 3;
    }
    let m_mean = diag_sum / count as f64;
    let (pp, ii, dd) = (p.m_bar * p.kd / ts, p.m_bar * p.kp / ts, p.m_bar / ts);
    Mismatch {
        m_bar: p.m_bar,
        lambda_min: lo,
        lambda_max: hi,
        joint_inertia_mean: m_mean,
        tde_lag_min_s: ts * lo / p.m_bar,
        tde_lag_max_s: ts * hi / p.m_bar,
        equiv_p: pp,
        equiv_i: ii,
        equiv_d: dd,
        equiv_freq_hz: (pp / m_mean).sqrt() / (2.0 * std::f64::consts::PI),
        equiv_zeta: dd / (2.0 * (pp * m_mean).sqrt()),
    }
}
