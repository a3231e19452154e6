//! Round-off sensitivity: how far a law's metrics move when its run is repeated with the plant
//! started one ulp away (the round-off twins, the supervisor's `loops::inproc::run_twins`: eight
//! ways), and how many digits of each figure survive the largest of those moves.
//!
//! Why: the super-twisting term k₁|s|^½ sign(s) is not Lipschitz at s = 0, so a difference of
//! 10⁻¹³ in s (round-off of the integrator, or of another implementation's operation order) can
//! grow to a percent of the RMS by the end of a run, while `tdc` and `pid` keep 10 or more
//! digits. A figure is only worth the digits its twin reproduces.

use serde::{Deserialize, Serialize};

/// What the twin changed, as `summary.json` and the reports say it.
pub const PERTURBATION: &str =
    "q(0) one ulp up and one ulp down in each joint alone and in all three together (8 twins)";

/// Below this relative spread a figure keeps every digit the reports print (4 significant).
pub const FULL_DIGITS_BELOW: f64 = 5e-5;

/// A law's metrics against its round-off twin's: relative spreads |a − b| / max(|a|, |b|), the
/// largest over the three joints (0 when both are 0; 1 when one is not finite).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Sensitivity {
    /// RMS joint tracking error (`rms_rad`).
    pub rms_rel: f64,
    /// Max |e_i| (`max_abs_err_rad`).
    pub max_err_rel: f64,
    /// RMS task-space error (`task_rms_mm`).
    pub task_rms_rel: f64,
    /// TDE error RMS (`tde_err_rms`); None for `pid`.
    pub tde_rel: Option<f64>,
    /// The max-joint RMS tracking error of the twin that moved it most, rad.
    pub twin_rms_rad: f64,
    /// How many twins the spreads are the largest of.
    #[serde(default = "one")]
    pub twins: u32,
    /// The median over the twins of the RMS spread (`rms_rel` is their largest).
    #[serde(default)]
    pub rms_rel_median: f64,
}

fn one() -> u32 {
    1
}

/// |a − b| / max(|a|, |b|): 0 for two zeros, 1 if either is not finite (nothing holds).
pub fn rel_spread(a: f64, b: f64) -> f64 {
    if !(a.is_finite() && b.is_finite()) {
        return if a.to_bits() == b.to_bits() { 0.0 } else { 1.0 };
    }
    let scale = a.abs().max(b.abs());
    if scale == 0.0 {
        0.0
    } else {
        ((a - b).abs() / scale).min(1.0)
    }
}

/// The largest [`rel_spread`] over three joints.
pub fn rel3(a: [f64; 3], b: [f64; 3]) -> f64 {
    (0..3).map(|j| rel_spread(a[j], b[j])).fold(0.0, f64::max)
}

impl Sensitivity {
    /// The largest of the spreads: the figure a report quotes for the law.
    pub fn worst(&self) -> f64 {
        [self.rms_rel, self.max_err_rel, self.task_rms_rel]
            .into_iter()
            .chain(self.tde_rel)
            .fold(0.0, f64::max)
    }
}

/// Significant digits of `x` that survive a relative spread `rel`: all 4 the reports print below
/// [`FULL_DIGITS_BELOW`], else down to the digit where the spread |x|·rel starts (that last digit
/// uncertain by less than one unit), at least 1. (1.234e-6 at 0.9 %: ±1.1e-8, so 1.2e-6.)
pub fn digits(x: f64, rel: f64) -> usize {
    if rel < FULL_DIGITS_BELOW {
        return 4;
    }
    let (x, dx) = (x.abs(), x.abs() * rel);
    if !(x > 0.0 && dx > 0.0 && dx.is_finite()) {
        // 0, or NaN / infinite: nothing to cut by, or nothing known.
        return if x == 0.0 { 4 } else { 1 };
    }
    let d = x.log10().floor() - dx.log10().floor();
    (d as i64).clamp(1, 4) as usize
}

/// `x` with `decimals` decimals, or fewer: no more significant digits than a relative spread
/// `rel` leaves ([`digits`]).
pub fn fixed(x: f64, decimals: usize, rel: f64) -> String {
    let sig = digits(x, rel) as i64;
    let lead = if x == 0.0 || !x.is_finite() {
        0
    } else {
        x.abs().log10().floor() as i64
    };
    let d = (sig - 1 - lead).clamp(0, decimals as i64) as usize;
    format!("{x:.d$}")
}

/// `x` in exponent form with the digits a relative spread leaves (4 when it leaves all).
pub fn sci(x: f64, rel: f64) -> String {
    format!("{x:.*e}", digits(x, rel) - 1)
}

/// A spread in words for the reports: `< 1e-9`, `2e-7`, `4e-4`, or `±0.9 %` (one or two significant
/// digits: the spread is itself one sample of round-off).
pub fn show_spread(rel: f64) -> String {
    if rel < 1e-9 {
        "< 1e-9".into()
    } else if rel < 1e-3 {
        format!("{rel:.0e}")
    } else if rel < 0.1 {
        format!("±{:.1} %", rel * 100.0)
    } else {
        format!("±{:.0} %", rel * 100.0)
    }
}

/// Why a twin may see nothing: an encoder quantises q, and a one-ulp change of the physics stays
/// inside one count unless a measurement sits on a count's edge. None without an encoder.
pub fn masked_note(cfg: &deltaloop_config::RunConfig) -> Option<String> {
    let counts = cfg.sensor.encoder_counts_per_rev;
    (counts > 0).then(|| {
        format!(
            "the encoder quantises q to {:.2} µrad ({counts} counts/rev): a one-ulp perturbation stays inside a count, so the round-off twins measure little here; repeats over sensor-noise seeds measure the spread",
            std::f64::consts::TAU / f64::from(counts) * 1e6
        )
    })
}

/// Whether a spread is large enough to say so next to the figure (a printed digit moves).
pub fn is_sensitive(rel: f64) -> bool {
    rel >= FULL_DIGITS_BELOW || rel.is_nan()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn digits_follow_the_spread() {
        let x = 1.23456e-6;
        assert_eq!(digits(x, 0.0), 4);
        assert_eq!(digits(x, 1e-10), 4);
        assert_eq!(digits(x, 4.9e-5), 4);
        assert_eq!(digits(x, 2e-4), 4); // ±2.5e-10: 1.235e-6, the 5 uncertain
        assert_eq!(digits(x, 2e-3), 3); // ±2.5e-9: 1.23e-6
        assert_eq!(digits(x, 0.009), 2); // ±1.1e-8: 1.2e-6
        assert_eq!(digits(9.9e-6, 0.009), 2); // ±8.9e-8: 9.9e-6, the 9 uncertain
        assert_eq!(digits(9.9e-6, 0.012), 1); // ±1.2e-7: the second digit is gone
        assert_eq!(digits(x, 0.5), 1);
        assert_eq!(digits(x, f64::NAN), 1);
        assert_eq!(digits(0.0, 0.5), 4);
        assert_eq!(sci(x, 0.009), "1.2e-6");
        assert_eq!(sci(x, 0.0), "1.235e-6");
        assert_eq!(sci(3.106e-5, 0.026), "3.1e-5");
    }

    #[test]
    fn spreads_are_relative_to_the_larger_and_saturate() {
        assert_eq!(rel_spread(2.0, 1.0), 0.5);
        assert_eq!(rel_spread(1.0, 2.0), 0.5);
        assert_eq!(rel_spread(0.0, 0.0), 0.0);
        assert_eq!(rel_spread(f64::NAN, 1.0), 1.0);
        assert_eq!(rel_spread(f64::INFINITY, f64::INFINITY), 0.0);
        assert_eq!(show_spread(3e-12), "< 1e-9");
        assert_eq!(show_spread(2.2e-7), "2e-7");
        assert_eq!(show_spread(4.4e-4), "4e-4");
        assert_eq!(show_spread(0.0094), "±0.9 %");
        assert_eq!(show_spread(0.25), "±25 %");
    }
}
