//! The one-sided energy spectrum of a real series after removing its end-to-end trend: the FFT
//! behind the study's chattering metric (docs/controllers.md, "What the study measures").
//!
//! Signal processing behind a plain `&[f64]` API, nothing of a run: the study's metrics call
//! it.

use rustfft::{FftPlanner, num_complex::Complex};

/// Plans FFTs and keeps them for series of the same length.
pub struct Spectra {
    planner: FftPlanner<f64>,
}

impl Default for Spectra {
    fn default() -> Self {
        Self::new()
    }
}

impl Spectra {
    pub fn new() -> Self {
        Self {
            planner: FftPlanner::new(),
        }
    }

    /// The one-sided energy spectrum of `x` (unit² for `x` in unit) after removing the straight
    /// line through its first and last samples: w_j·|X_j|² for j = 0..=n/2 (w = 2 but at DC and
    /// Nyquist), X the unnormalised DFT. Empty for fewer than two samples.
    pub fn detrended(&mut self, x: &[f64]) -> Vec<f64> {
        let n = x.len();
        if n < 2 {
            return Vec::new();
        }
        let (first, last) = (x[0], x[n - 1]);
        let mut buf: Vec<Complex<f64>> = x
            .iter()
            .enumerate()
            .map(|(k, &v)| {
                Complex::new(
                    v - (first + (last - first) * k as f64 / (n - 1) as f64),
                    0.0,
                )
            })
            .collect();
        self.planner.plan_fft_forward(n).process(&mut buf);
        buf.iter()
            .enumerate()
            .take(n / 2 + 1)
            .map(|(j, c)| {
                let w = if j == 0 || (n.is_multiple_of(2) && j == n / 2) {
                    1.0
                } else {
                    2.0
                };
                w * c.norm_sqr()
            })
            .collect()
    }
}
