//! Seeded repeats summarised: mean, sample standard deviation and the t-based 95 % confidence
//! interval of the mean, for any metric the sweeps and the paper repeat over sensor-noise seeds
//! (and, in realtime, over runs).
//!
//! The interval is Student's t: mean ± t₀.₉₇₅,ₙ₋₁ · s/√n, with s the sample standard deviation
//! (n − 1 in the denominator). It assumes the repeats are independent and their mean roughly
//! normal; with 20 repeats of a tracking error that holds well enough, and it is the interval a
//! reader can recompute from the columns.

use serde::{Deserialize, Serialize};
use statrs::distribution::{ContinuousCDF, StudentsT};

/// The repeats of one metric, summarised.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Interval {
    /// Repeats with a finite value (the others are left out and counted in `dropped`).
    pub n: usize,
    /// Repeats whose value was not finite (a diverged or failed run).
    pub dropped: usize,
    pub mean: f64,
    /// Sample standard deviation (n − 1); NaN for n < 2.
    pub std: f64,
    /// Lower end of the t-based 95 % confidence interval of the mean; NaN for n < 2.
    pub ci95_lo: f64,
    /// Upper end.
    pub ci95_hi: f64,
}

/// Which interval [`Interval`] is, in the words the docs and the reports use.
pub const CI_METHOD: &str =
    "t-based 95 % confidence interval of the mean (Student t, n − 1 degrees of freedom)";

/// t₀.₉₇₅ with `dof` degrees of freedom (dof ≥ 1).
pub fn t975(dof: usize) -> f64 {
    StudentsT::new(0.0, 1.0, dof as f64)
        .map(|t| t.inverse_cdf(0.975))
        .unwrap_or(f64::NAN)
}

impl Interval {
    /// Mean, standard deviation and CI of the finite values of `xs`; None when none is finite.
    pub fn of(xs: &[f64]) -> Option<Self> {
        let finite: Vec<f64> = xs.iter().copied().filter(|x| x.is_finite()).collect();
        let n = finite.len();
        if n == 0 {
            return None;
        }
        let mean = finite.iter().sum::<f64>() / n as f64;
        let (std, half) = if n < 2 {
            (f64::NAN, f64::NAN)
        } else {
            let var = finite.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1) as f64;
            let std = var.sqrt();
            (std, t975(n - 1) * std / (n as f64).sqrt())
        };
        Some(Self {
            n,
            dropped: xs.len() - n,
            mean,
            std,
            ci95_lo: mean - half,
            ci95_hi: mean + half,
        })
    }

    /// Half the interval's width (NaN for n < 2).
    pub fn half_width(&self) -> f64 {
        (self.ci95_hi - self.ci95_lo) / 2.0
    }

    /// Whether the whole interval lies below `x` (the mean is below it beyond the 95 % level);
    /// false for n < 2 (no interval).
    pub fn below(&self, x: f64) -> bool {
        self.ci95_hi < x
    }

    /// Whether the whole interval lies above `x`.
    pub fn above(&self, x: f64) -> bool {
        self.ci95_lo > x
    }

    /// `mean [lo, hi]` with `d` decimals, for the reports.
    pub fn show(&self, d: usize) -> String {
        if self.n < 2 {
            return format!("{:.d$} (n = {})", self.mean, self.n);
        }
        format!(
            "{:.d$} [{:.d$}, {:.d$}]",
            self.mean, self.ci95_lo, self.ci95_hi
        )
    }
}

/// Two-sided p-value of Student's one-sample t-test that a mean of `n` values with sample
/// standard deviation `std` is 0: 2·(1 − F(|t|)), t = mean/(std/√n), n − 1 degrees of freedom.
/// NaN for n < 2; with `std` 0 it is 1 for a mean of 0 and 0 otherwise.
pub fn t_test_p(mean: f64, std: f64, n: usize) -> f64 {
    if n < 2 || !(mean.is_finite() && std.is_finite()) {
        return f64::NAN;
    }
    if std == 0.0 {
        return if mean == 0.0 { 1.0 } else { 0.0 };
    }
    let t = mean / (std / (n as f64).sqrt());
    StudentsT::new(0.0, 1.0, (n - 1) as f64)
        .map(|d| 2.0 * d.sf(t.abs()))
        .unwrap_or(f64::NAN)
}

/// Holm's step-down correction of `p` for their number (family-wise error rate): sorted
/// ascending, the i-th smallest becomes max over j ≤ i of min(1, (m − j + 1)·p₍ⱼ₎), m the number
/// of finite p-values; NaN entries are not tests and stay NaN. Returned in the input's order.
pub fn holm(p: &[f64]) -> Vec<f64> {
    let mut order: Vec<usize> = (0..p.len()).filter(|&i| p[i].is_finite()).collect();
    order.sort_by(|&a, &b| p[a].total_cmp(&p[b]));
    let m = order.len();
    let mut out = vec![f64::NAN; p.len()];
    let mut running = 0.0f64;
    for (j, &i) in order.iter().enumerate() {
        running = running.max(((m - j) as f64 * p[i]).min(1.0));
        out[i] = running;
    }
    out
}

/// Which correction the robustness verdicts take, in the words of the reports.
pub const CORRECTION: &str = "Holm's step-down correction over every ratio of the table with 5 or more runs (family-wise error 5 %)";

/// Repeated ratios (law A's RMS over law B's, run by run) summarised in log space: the geometric
/// mean and the t-based 95 % CI of the mean log ratio, mapped back. Tracking errors are
/// heavy-tailed in realtime (one missed deadline multiplies a run's RMS), and a ratio's natural
/// scale is multiplicative: in log space the interval is always positive, and B/A gets exactly
/// the reciprocal interval of A/B.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct RatioInterval {
    /// Ratios that were finite and positive.
    pub n: usize,
    pub geo_mean: f64,
    pub ci95_lo: f64,
    pub ci95_hi: f64,
    /// Standard deviation of the log ratio (NaN for n < 2).
    pub log_std: f64,
    /// Two-sided p-value of the one-sample t-test that the mean log ratio is 0 (the ratio 1):
    /// below 0.05 exactly when the interval excludes 1; NaN for n < 2.
    pub p_value: f64,
}

/// Which interval [`RatioInterval`] is.
pub const RATIO_CI_METHOD: &str = "geometric mean with the t-based 95 % confidence interval of the mean log ratio (Student t, n − 1 degrees of freedom)";

impl RatioInterval {
    /// The interval of the positive finite values of `ratios`; None when there is none.
    pub fn of(ratios: &[f64]) -> Option<Self> {
        let logs: Vec<f64> = ratios
            .iter()
            .filter(|r| r.is_finite() && **r > 0.0)
            .map(|r| r.ln())
            .collect();
        let i = Interval::of(&logs)?;
        Some(Self {
            n: i.n,
            geo_mean: i.mean.exp(),
            ci95_lo: i.ci95_lo.exp(),
            ci95_hi: i.ci95_hi.exp(),
            log_std: i.std,
            p_value: t_test_p(i.mean, i.std, i.n),
        })
    }

    /// Whether the whole interval lies below `x`.
    pub fn below(&self, x: f64) -> bool {
        self.ci95_hi < x
    }

    /// Whether the whole interval lies above `x`.
    pub fn above(&self, x: f64) -> bool {
        self.ci95_lo > x
    }

    /// `geo_mean [lo, hi]` with 3 significant digits, for the reports.
    pub fn show(&self) -> String {
        // Three significant digits (a value that underflowed to 0 or overflowed: as it is).
        let g = |x: f64| {
            if !(x.is_finite() && x > 0.0) {
                return format!("{x}");
            }
            let d = (2 - x.log10().floor() as i64).clamp(0, 6) as usize;
            format!("{x:.d$}")
        };
        if self.n < 2 {
            return format!("{} (n = {})", g(self.geo_mean), self.n);
        }
        format!(
            "{} [{}, {}]",
            g(self.geo_mean),
            g(self.ci95_lo),
            g(self.ci95_hi)
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// By hand: p = 0.01, 0.04, 0.03, 0.005 (m = 4) sorted 0.005, 0.01, 0.03, 0.04 → 4·0.005 =
    /// 0.02, 3·0.01 = 0.03, 2·0.03 = 0.06, max(0.06, 1·0.04) = 0.06; NaN is no test.
    #[test]
    fn holm_matches_the_hand_computed_case() {
        let h = holm(&[0.01, 0.04, f64::NAN, 0.03, 0.005]);
        let want = [0.03, 0.06, f64::NAN, 0.06, 0.02];
        for (a, b) in h.iter().zip(want) {
            assert!((a.is_nan() && b.is_nan()) || (a - b).abs() < 1e-15, "{h:?}");
        }
        assert_eq!(holm(&[0.5, 0.9]), vec![1.0, 1.0]);
    }

    /// By hand, 2 degrees of freedom (F(t) = 1/2 + t/(2√(2 + t²))): logs 1, 2, 3 → mean 2,
    /// s = 1, t = 2√3 = 3.4641016, F = 1/2 + 3.4641016/(2√14) = 0.96291005, p = 0.0741799.
    #[test]
    fn the_t_test_p_value_matches_the_closed_form_for_two_degrees_of_freedom() {
        let p = t_test_p(2.0, 1.0, 3);
        let t = 2.0 * 3f64.sqrt();
        let closed = 2.0 * (0.5 - t / (2.0 * (2.0 + t * t).sqrt()));
        assert!((p - closed).abs() < 1e-12, "{p} vs {closed}");
        assert!((p - 0.0741799).abs() < 1e-6, "{p}");
        let e = std::f64::consts::E;
        let r = RatioInterval::of(&[e, e * e, e * e * e]).unwrap();
        assert!((r.p_value - closed).abs() < 1e-12);
        // p < 0.05 exactly when the interval excludes 1.
        assert_eq!(r.p_value < 0.05, r.above(1.0) || r.below(1.0));
    }

    /// Hand-computed: xs = 1, 2, 3, 4, 5 → mean 3, s² = 10/4 = 2.5, s = 1.5811388300841898,
    /// s/√5 = 0.7071067811865476, t₀.₉₇₅,₄ = 2.7764451051977987 (tables: 2.776),
    /// half-width = 1.9632431619... → [1.0367568, 4.9632432].
    #[test]
    fn interval_matches_the_hand_computed_case() {
        let i = Interval::of(&[1.0, 2.0, 3.0, 4.0, 5.0]).unwrap();
        assert_eq!((i.n, i.dropped), (5, 0));
        assert_eq!(i.mean, 3.0);
        assert!((i.std - 1.5811388300841898).abs() < 1e-15);
        assert!((t975(4) - 2.7764451051977987).abs() < 1e-9, "{}", t975(4));
        assert!(
            (i.half_width() - 1.963243161).abs() < 1e-8,
            "{}",
            i.half_width()
        );
        assert!((i.ci95_lo - 1.036756839).abs() < 1e-8);
        assert!((i.ci95_hi - 4.963243161).abs() < 1e-8);
        // Printed t tables: 12.706 (1), 2.093 (19), 2.045 (29); → 1.960 for large n.
        for (dof, t) in [(1, 12.706), (19, 2.093), (29, 2.045), (100_000, 1.960)] {
            assert!((t975(dof) - t).abs() < 5e-4, "dof {dof}: {}", t975(dof));
        }
    }

    /// Hand-computed: ratios 1, e, e² → logs 0, 1, 2: mean 1, s = 1, t₀.₉₇₅,₂ = 4.302652729911275,
    /// half = 4.3027/√3 = 2.484137... → geometric mean e, [e^−1.484137, e^3.484137].
    #[test]
    fn ratio_interval_is_the_log_space_interval_mapped_back() {
        let e = std::f64::consts::E;
        let r = RatioInterval::of(&[1.0, e, e * e, 0.0, -1.0]).unwrap();
        assert_eq!(r.n, 3);
        assert!((r.geo_mean - e).abs() < 1e-12);
        assert!((r.log_std - 1.0).abs() < 1e-12);
        let half = 4.302652729911275 / 3f64.sqrt();
        let close = |a: f64, b: f64| (a / b - 1.0).abs() < 1e-7;
        assert!(close(r.ci95_lo, (1.0 - half).exp()), "{r:?}");
        assert!(close(r.ci95_hi, (1.0 + half).exp()), "{r:?}");
        // The reciprocal ratios give the reciprocal interval.
        let inv = RatioInterval::of(&[1.0, 1.0 / e, 1.0 / (e * e)]).unwrap();
        assert!((inv.ci95_lo * r.ci95_hi - 1.0).abs() < 1e-12);
        assert!(RatioInterval::of(&[0.5, 0.6, 0.55]).unwrap().below(1.0));
        assert_eq!(
            RatioInterval::of(&[77.5, 77.5]).unwrap().show(),
            "77.5 [77.5, 77.5]"
        );
        assert_eq!(
            RatioInterval::of(&[0.0123]).unwrap().show(),
            "0.0123 (n = 1)"
        );
    }

    #[test]
    fn non_finite_repeats_are_dropped_and_one_repeat_has_no_interval() {
        let i = Interval::of(&[2.0, f64::NAN, 4.0, f64::INFINITY]).unwrap();
        assert_eq!((i.n, i.dropped, i.mean), (2, 2, 3.0));
        assert!((i.std - std::f64::consts::SQRT_2).abs() < 1e-15);
        let one = Interval::of(&[7.0]).unwrap();
        assert!(one.std.is_nan() && one.ci95_lo.is_nan());
        assert_eq!(one.show(1), "7.0 (n = 1)");
        assert!(Interval::of(&[f64::NAN]).is_none());
        assert!(Interval::of(&[]).is_none());
        assert!(Interval::of(&[1.0, 1.0, 1.0]).unwrap().below(1.0 + 1e-12));
    }
}
