//! Paired comparisons of the laws: replica r meets the same latencies in every law (common random
//! numbers), so two laws are compared replica by replica, not distribution against distribution.

use deltaloop_study::record::metrics::percentile_type7;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Serialize;

/// Bootstrap resamples of a pair's ratios.
pub const RESAMPLES: usize = 2000;

/// Law `a` against law `b` over the same replicas.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Pair {
    pub a: String,
    pub b: String,
    /// The share of the replicas whose max-joint RMS of `a` is strictly below `b`'s; a replica
    /// that diverged or faulted (null) ranks worst, two nulls tie.
    pub a_better_share: f64,
    /// Replicas both laws completed: the ratios below are over them.
    pub compared: u64,
    /// The median over those replicas of RMS_a / RMS_b, and its 95 % bootstrap interval
    /// ([`RESAMPLES`] resamples of the replicas, percentile method); null without a replica.
    pub ratio_p50: Option<f64>,
    pub ratio_ci95: Option<[f64; 2]>,
}

impl Pair {
    /// `a` against `b` from their per-replica values (replica order, None: diverged or faulted).
    /// The bootstrap draws from `seed`.
    pub fn of((a, va): (&str, &[Option<f64>]), (b, vb): (&str, &[Option<f64>]), seed: u64) -> Self {
        let n = va.len().min(vb.len());
        let better = va
            .iter()
            .zip(vb)
            .filter(|(x, y)| match (x, y) {
                (Some(x), Some(y)) => x < y,
                (Some(_), None) => true,
                _ => false,
            })
            .count();
        let ratios: Vec<f64> = va
            .iter()
            .zip(vb)
            .filter_map(|(x, y)| Some(x.as_ref()? / y.as_ref()?))
            .filter(|r| r.is_finite())
            .collect();
        let (ratio_p50, ratio_ci95) = if ratios.is_empty() {
            (None, None)
        } else {
            (
                Some(percentile_type7(&mut ratios.clone(), 0.5)),
                Some(bootstrap_median_ci(&ratios, seed)),
            )
        };
        Self {
            a: a.to_string(),
            b: b.to_string(),
            a_better_share: better as f64 / n.max(1) as f64,
            compared: ratios.len() as u64,
            ratio_p50,
            ratio_ci95,
        }
    }

    /// Which law wins and how surely, in one sentence.
    pub fn sentence(&self) -> String {
        let (win, lose, share) = if self.a_better_share >= 0.5 {
            (&self.a, &self.b, self.a_better_share)
        } else {
            (&self.b, &self.a, 1.0 - self.a_better_share)
        };
        let ratio = match (self.ratio_p50, self.ratio_ci95) {
            (Some(r), Some([lo, hi])) => format!(
                "; RMS {} / {}: median {r:.3e} (95 % CI {lo:.3e}–{hi:.3e}) over the {} replicas both completed",
                self.a, self.b, self.compared
            ),
            _ => "; no replica both completed".into(),
        };
        let verdict = if self.ratio_ci95.is_some_and(|[lo, hi]| hi < 1.0 || lo > 1.0) {
            "the interval excludes 1: the difference is real at these latencies"
        } else {
            "the interval includes 1: these latencies do not tell them apart"
        };
        format!(
            "`{win}` beats `{lose}` in {:.0} % of the replicas{ratio}; {verdict}.",
            share * 100.0
        )
    }
}

/// The 95 % percentile-bootstrap interval of the median of `x`.
fn bootstrap_median_ci(x: &[f64], seed: u64) -> [f64; 2] {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut sample = vec![0.0; x.len()];
    let mut medians: Vec<f64> = (0..RESAMPLES)
        .map(|_| {
            for s in sample.iter_mut() {
                *s = x[rng.random_range(0..x.len())];
            }
            percentile_type7(&mut sample, 0.5)
        })
        .collect();
    [
        percentile_type7(&mut medians, 0.025),
        percentile_type7(&mut medians, 0.975),
    ]
}

/// Every pair of `laws` (in their order: the first against each later one), each with its
/// per-replica values.
pub fn all(laws: &[(String, Vec<Option<f64>>)], seed: u64) -> Vec<Pair> {
    let mut v = Vec::new();
    for (i, (a, va)) in laws.iter().enumerate() {
        for (b, vb) in &laws[i + 1..] {
            v.push(Pair::of((a, va), (b, vb), seed));
        }
    }
    v
}

#[cfg(test)]
mod tests {
    use super::*;

    /// a is half of b in every replica both completed; a diverged once (worst), b once (a better).
    #[test]
    fn shares_count_nulls_as_worst_and_ratios_only_where_both_completed() {
        let a = [Some(1.0), Some(2.0), None, Some(4.0), Some(5.0)];
        let b = [Some(2.0), Some(4.0), Some(1.0), None, Some(10.0)];
        let p = Pair::of(("a", &a), ("b", &b), 1);
        assert_eq!(p.a_better_share, 4.0 / 5.0);
        assert_eq!(p.compared, 3);
        assert_eq!(p.ratio_p50, Some(0.5));
        assert_eq!(p.ratio_ci95, Some([0.5, 0.5]));
        assert!(
            p.sentence().starts_with("`a` beats `b` in 80 %"),
            "{}",
            p.sentence()
        );
        assert!(p.sentence().contains("excludes 1"));
        let none = Pair::of(("a", &[None, None]), ("b", &[None, None]), 1);
        assert_eq!((none.a_better_share, none.ratio_p50), (0.0, None));
    }

    /// Ratios spread around 1: the bootstrap interval holds the median and includes 1; it is
    /// the same for the same seed.
    #[test]
    fn a_bootstrap_interval_around_one_says_they_cannot_be_told_apart() {
        let a: Vec<Option<f64>> = (0..200)
            .map(|i| Some(1.0 + (i % 7) as f64 * 0.01))
            .collect();
        let b: Vec<Option<f64>> = (0..200)
            .map(|i| Some(1.0 + (i % 5) as f64 * 0.01))
            .collect();
        let p = Pair::of(("a", &a), ("b", &b), 9);
        let [lo, hi] = p.ratio_ci95.unwrap();
        assert!(lo <= p.ratio_p50.unwrap() && p.ratio_p50.unwrap() <= hi);
        assert!(lo <= 1.0 && 1.0 <= hi, "{lo} {hi}");
        assert_eq!(Pair::of(("a", &a), ("b", &b), 9), p);
        assert!(p.sentence().contains("do not tell them apart"));
        let laws = vec![
            ("x".to_string(), a.clone()),
            ("y".to_string(), b.clone()),
            ("z".to_string(), a),
        ];
        let all = all(&laws, 9);
        let names: Vec<_> = all.iter().map(|p| (p.a.as_str(), p.b.as_str())).collect();
        assert_eq!(names, [("x", "y"), ("x", "z"), ("y", "z")]);
    }
}
