//! The study's metrics (docs/controllers.md, "What the study measures"): pure functions of a
//! finished run, its reference and the controller constants.

use crate::record::{LawRun, Outcome};
use crate::reference::JointReference;
use deltaloop_law::{ControllerParams, Law};
use deltaloop_model::{DeltaRobot, Vec3};
use rustfft::{FftPlanner, num_complex::Complex};
use serde::Serialize;

/// High-frequency threshold for torque content, Hz.
pub const HF_CUTOFF_HZ: u64 = 100;

/// Per-law metrics, as written to `summary.json`. Arrays are per joint [1, 2, 3].
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct LawMetrics {
    pub law: Law,
    /// Ticks after tick 0 the metrics cover (k = 0..=N); fewer if the run diverged.
    pub ticks: u64,
    /// Whether every tick 0..=N ran and was recorded.
    pub completed: bool,
    /// Ticks the supervisor lost (its queues overflowed): not in the metrics.
    pub lost_ticks: u64,
    /// Why the run ended as "lost data", if it did.
    pub lost_data: Option<String>,
    /// Tick at which the run diverged, if it did.
    pub diverged_at_tick: Option<u64>,
    pub diverged_reason: Option<String>,
    /// Tick at which Ctrl-C / SIGTERM stopped the run, if it did.
    pub interrupted_at_tick: Option<u64>,
    /// Tick and cause of a loop fault (a process died or stalled), if any.
    pub fault_at_tick: Option<u64>,
    pub fault: Option<String>,
    /// RMS joint tracking error over k = 0..=N, rad.
    pub rms_rad: [f64; 3],
    /// Max |e_i| over k = 0..=N, rad.
    pub max_abs_err_rad: [f64; 3],
    /// RMS of the task-space error |FK(q_k) − x_d(t_k)|, mm.
    pub task_rms_mm: f64,
    /// Max task-space error, mm.
    pub task_max_mm: f64,
    /// Max |τ_i| of the commanded torque over k = 0..N−1, N m.
    pub max_abs_tau_nm: [f64; 3],
    /// Total variation Σ_{k=1}^{N−1} |τ_{i,k} − τ_{i,k−1}| of the commanded torque, N m.
    pub torque_tv_nm: [f64; 3],
    /// Intervals (k = 0..N−1) in which the plant clamped some joint.
    pub clamp_count: u64,
    /// Intervals in which the plant held the previous torque (missed or rejected command).
    pub held_count: u64,
    /// Commands the plant rejected (non-finite, or over the limit under `faults.torque_limit = "reject"`).
    pub rejected_count: u64,
    /// RMS of the detrended commanded torque above 100 Hz, N m.
    pub hf_torque_rms_nm: [f64; 3],
    /// Share of the detrended torque energy above 100 Hz (0..1).
    pub hf_torque_share: [f64; 3],
    /// Frequency of the largest non-DC torque spectral line, Hz (a limit cycle shows here).
    pub torque_peak_hz: [f64; 3],
    /// RMS of the TDE error Ñ_k = N̂_k − N_k over k = 0..N−1, rad/s² (null for `pid`).
    pub tde_err_rms: Option<[f64; 3]>,
    /// max_k |Ñ_k − Ñ_{k−1}|/Ts over k = 1..N−1, rad/s³ (null for `pid`).
    pub delta_n_max: Option<[f64; 3]>,
    /// 99.9th percentile (type 7) of |Ñ_k − Ñ_{k−1}|/Ts, rad/s³ (null for `pid`).
    pub delta_n_p999: Option<[f64; 3]>,
    /// The k2 that paper eq. 43 demands: δ(δ + 3k1²)/(2k1²), δ = max over joints of δ_N, rad/s³.
    pub k2_required: Option<f64>,
    /// The k2 of the constants in use, rad/s³.
    pub k2_in_use: f64,
    /// Whether k2_in_use exceeds k2_required (a sufficient condition only: reported, not enforced).
    pub eq43_holds: Option<bool>,
}

/// RMS of a series (0 for an empty one).
pub fn rms(xs: impl ExactSizeIterator<Item = f64>) -> f64 {
    let n = xs.len();
    if n == 0 {
        return 0.0;
    }
    (xs.map(|x| x * x).sum::<f64>() / n as f64).sqrt()
}

/// Percentile p ∈ [0, 1] with linear interpolation between order statistics (Hyndman–Fan type 7,
/// numpy's default). Sorts `xs` in place. NaN for an empty slice.
pub fn percentile_type7(xs: &mut [f64], p: f64) -> f64 {
    if xs.is_empty() {
        return f64::NAN;
    }
    xs.sort_by(f64::total_cmp);
    let h = (xs.len() - 1) as f64 * p;
    let lo = h.floor() as usize;
    let hi = (lo + 1).min(xs.len() - 1);
    xs[lo] + (h - lo as f64) * (xs[hi] - xs[lo])
}

/// High-frequency content of a torque series sampled every `ts` s: (HF RMS in N m, HF energy
/// share, frequency of the largest non-DC line in Hz). The straight line through the first and
/// last samples is removed; a one-sided bin j is high-frequency iff j/(n·Ts) > 100 Hz, decided
/// on integers from Ts in ns.
pub fn high_frequency(tau: &[f64], ts: f64) -> (f64, f64, f64) {
    let n = tau.len();
    if n < 3 {
        return (0.0, 0.0, 0.0);
    }
    let (first, last) = (tau[0], tau[n - 1]);
    let mut buf: Vec<Complex<f64>> = tau
        .iter()
        .enumerate()
        .map(|(k, &x)| {
            Complex::new(
                x - (first + (last - first) * k as f64 / (n - 1) as f64),
                0.0,
            )
        })
        .collect();
    FftPlanner::new().plan_fft_forward(n).process(&mut buf);
    let (mut total, mut hf, mut peak, mut peak_j) = (0.0, 0.0, 0.0, 0usize);
    for (j, x) in buf.iter().enumerate().take(n / 2 + 1) {
        let w = if j == 0 || (n.is_multiple_of(2) && j == n / 2) {
            1.0
        } else {
            2.0
        };
        let e = w * x.norm_sqr();
        total += e;
        if is_high_frequency(j, n, ts) {
            hf += e;
        }
        if j > 0 && e > peak {
            peak = e;
            peak_j = j;
        }
    }
    let share = if total > 0.0 { hf / total } else { 0.0 };
    (hf.sqrt() / n as f64, share, peak_j as f64 / (n as f64 * ts))
}

/// Whether one-sided bin j of an n-point FFT at period `ts` (s) lies above [`HF_CUTOFF_HZ`]:
/// j/(n·Ts) > f_c, decided on integers (j·10⁹ > f_c·n·Ts[ns]) so a bin exactly at the cutoff is out.
pub fn is_high_frequency(j: usize, n: usize, ts: f64) -> bool {
    let ts_ns = (ts * 1e9).round() as u128;
    (j as u128) * 1_000_000_000 > u128::from(HF_CUTOFF_HZ) * n as u128 * ts_ns
}

/// The k2 that paper eq. 43 demands for TDE-error derivative bound δ_N and gain k1.
pub fn k2_required(delta_n: f64, k1: f64) -> f64 {
    delta_n * (delta_n + 3.0 * k1 * k1) / (2.0 * k1 * k1)
}

fn per_joint(f: impl Fn(usize) -> f64) -> [f64; 3] {
    [f(0), f(1), f(2)]
}

/// Computes every metric of a run.
pub fn compute(
    run: &LawRun,
    reference: &JointReference,
    robot: &DeltaRobot,
    params: &ControllerParams,
) -> LawMetrics {
    let ts = reference.ts;
    let recs = &run.records;
    // Error metrics over k = 0..=N (or up to the divergence tick).
    let err = |i: usize| {
        recs.iter()
            .map(move |r| reference.rows[r.sample.k as usize].joint.q[i] - r.q_true[i])
    };
    let rms_rad = per_joint(|i| rms(err(i)));
    let max_abs_err_rad = per_joint(|i| err(i).fold(0.0, |m, e| m.max(e.abs())));
    let task_err_mm: Vec<f64> = recs
        .iter()
        .map(|r| match robot.fk(&r.q_true) {
            Ok(x) => (x - reference.rows[r.sample.k as usize].task.x).norm() * 1e3,
            Err(_) => f64::NAN,
        })
        .collect();
    let task_rms_mm = rms(task_err_mm.iter().copied());
    let task_max_mm = task_err_mm.iter().fold(0.0f64, |m, &e| m.max(e));

    // Torque metrics over k = 0..N−1: the intervals whose command the plant applied. (With lost
    // ticks the series has holes: differences across one are left out; the spectrum treats the
    // series as evenly sampled.)
    let n_tau = recs
        .iter()
        .take_while(|r| (r.sample.k as usize) < reference.n)
        .count()
        .max(usize::from(!recs.is_empty()));
    let taus = &recs[..n_tau];
    let tau = |i: usize| taus.iter().map(move |r| r.tau[i]);
    let max_abs_tau_nm = per_joint(|i| tau(i).fold(0.0, |m, t| m.max(t.abs())));
    let torque_tv_nm = per_joint(|i| {
        taus.windows(2)
            .filter(|w| w[1].sample.k == w[0].sample.k + 1)
            .map(|w| (w[1].tau[i] - w[0].tau[i]).abs())
            .sum()
    });
    let clamp_count = taus.iter().filter(|r| r.clamped).count() as u64;
    let held_count = taus.iter().filter(|r| r.held).count() as u64;
    let rejected_count = taus.iter().filter(|r| r.rejected).count() as u64;
    let hf: [(f64, f64, f64); 3] =
        std::array::from_fn(|i| high_frequency(&tau(i).collect::<Vec<_>>(), ts));

    // TDE error Ñ_k = N̂_k − N_k, N_k = (q̇_{k+1} − q̇_k)/Ts − τᵃ_{k+1}/M̄ from true rates, k = 0..N−1.
    // A tick the controller never answered, or whose next tick was lost, has no Ñ: it is left
    // out, and so are the differences that would span it.
    let mut n_tilde: Vec<Option<Vec3>> = Vec::with_capacity(n_tau);
    for (i, r) in taus.iter().enumerate() {
        if i > 0 && r.sample.k > taus[i - 1].sample.k + 1 {
            n_tilde.push(None);
        }
        let truth = run
            .next_of(i)
            .map(|(qd1, tau1)| (qd1 - r.qd_true) / ts - tau1 / params.m_bar);
        n_tilde.push(r.out.zip(truth).map(|(o, t)| o.n_hat - t));
    }
    let uses_tde = run.law.uses_tde();
    let answered: Vec<Vec3> = n_tilde.iter().flatten().copied().collect();
    let tde_err_rms = uses_tde.then(|| per_joint(|i| rms(answered.iter().map(|v| v[i]))));
    let dn = |i: usize| -> Vec<f64> {
        n_tilde
            .windows(2)
            .filter_map(|w| Some(((w[1]?[i] - w[0]?[i]) / ts).abs()))
            .collect()
    };
    let delta_n_max = uses_tde.then(|| per_joint(|i| dn(i).into_iter().fold(0.0, f64::max)));
    let delta_n_p999 = uses_tde.then(|| per_joint(|i| percentile_type7(&mut dn(i), 0.999)));
    let k2_req = delta_n_max.map(|d| k2_required(d.into_iter().fold(0.0, f64::max), params.k1));

    let lost_data = match (&run.outcome, run.first_lost) {
        (Outcome::LostData, Some(first)) => Some(format!(
            "the supervisor lost {} ticks of the stream, the first at tick {first}: it fell behind the loop and its queues overflowed; every tick it saw is recorded",
            run.lost_ticks
        )),
        _ => None,
    };
    let (completed, diverged_at_tick, diverged_reason) = match &run.outcome {
        Outcome::Diverged { tick, reason } => (false, Some(*tick), Some(reason.clone())),
        Outcome::Completed => (true, None, None),
        _ => (false, None, None),
    };
    let interrupted_at_tick = match run.outcome {
        Outcome::Interrupted { tick } => Some(tick),
        _ => None,
    };
    let (fault_at_tick, fault) = run.fault.clone().map(|f| (f.tick, f.cause)).unzip();
    LawMetrics {
        law: run.law,
        ticks: recs.len().saturating_sub(1) as u64,
        lost_ticks: run.lost_ticks,
        lost_data,
        completed,
        diverged_at_tick,
        diverged_reason,
        interrupted_at_tick,
        fault_at_tick,
        fault,
        rms_rad,
        max_abs_err_rad,
        task_rms_mm,
        task_max_mm,
        max_abs_tau_nm,
        torque_tv_nm,
        clamp_count,
        held_count,
        rejected_count,
        hf_torque_rms_nm: hf.map(|h| h.0),
        hf_torque_share: hf.map(|h| h.1),
        torque_peak_hz: hf.map(|h| h.2),
        tde_err_rms,
        delta_n_max,
        delta_n_p999,
        k2_required: k2_req,
        k2_in_use: params.k2,
        eq43_holds: k2_req.map(|r| params.k2 > r),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn percentile_matches_numpy_type7() {
        // numpy.percentile([1, 2, 3, 4, 10], 99.9) = 9.976
        let mut xs = [4.0, 1.0, 10.0, 3.0, 2.0];
        assert!((percentile_type7(&mut xs, 0.999) - 9.976).abs() < 1e-12);
        let mut ys = [5.0, 1.0];
        assert_eq!(percentile_type7(&mut ys, 0.5), 3.0);
        assert!(percentile_type7(&mut [], 0.5).is_nan());
    }

    #[test]
    fn hf_share_of_pure_tones() {
        let ts = 3e-4;
        // 1001 samples span exactly 0.3 s, so 20 Hz and 200 Hz tones end on zero like they start and
        // the detrend line is zero. Bin spacing 1/(n Ts) ≈ 3.33 Hz; 100 Hz sits at bin ≈ 30.
        let tone = |f: f64| -> Vec<f64> {
            (0..1001)
                .map(|k| (2.0 * std::f64::consts::PI * f * k as f64 * ts).sin())
                .collect()
        };
        // 20 Hz is all low; 200 Hz is all high (up to a little leakage).
        let (_, low_share, low_peak) = high_frequency(&tone(20.0), ts);
        let (hf_rms, high_share, high_peak) = high_frequency(&tone(200.0), ts);
        assert!(low_share < 1e-3, "{low_share}");
        assert!(high_share > 0.995, "{high_share}");
        assert!(
            (low_peak - 20.0).abs() < 0.5 && (high_peak - 200.0).abs() < 0.5,
            "{low_peak} {high_peak}"
        );
        // A unit sine has RMS 1/√2 (the detrend line is ~0 here).
        assert!((hf_rms - 0.5f64.sqrt()).abs() < 5e-3, "{hf_rms}");
        // Bin 30 of n = 1000 at Ts = 0.3 ms is exactly 100 Hz and is not high-frequency
        // (100·30 > 3·1000 is false); bin 31 is.
        assert!(!is_high_frequency(30, 1000, ts));
        assert!(is_high_frequency(31, 1000, ts));
        assert!(!is_high_frequency(3, 100, ts) && is_high_frequency(4, 100, ts));
    }

    #[test]
    fn linear_torque_has_no_hf_content() {
        let tau: Vec<f64> = (0..500).map(|k| 3.0 + 0.01 * k as f64).collect();
        // The detrended series is round-off only, so the HF RMS (not the share of round-off) is ~0.
        let (r, _, _) = high_frequency(&tau, 3e-4);
        assert!(r < 1e-12, "{r}");
    }

    #[test]
    fn eq43_k2_requirement() {
        // δ = 0 needs nothing; δ = k1² needs δ·4k1²/(2k1²) = 2δ.
        assert_eq!(k2_required(0.0, 700.0), 0.0);
        assert!((k2_required(4.0, 2.0) - 8.0).abs() < 1e-12);
    }
}
