//! The replicas' spread, per law and scale, as `whatif.json` holds it.

use super::draw::{Model, Pool};
use super::source::Source;
use deltaloop_config::Law;
use deltaloop_plant_tick::ReplyOutcome;
use deltaloop_study::Study;
use deltaloop_study::record::RunStatus;
use deltaloop_study::record::metrics::{LawMetrics, percentile_type7};
use deltaloop_study::record::stats::Interval;
use serde::Serialize;
use std::path::Path;

/// A JSON object whose keys keep their order: the laws as the config lists them, the scales
/// ascending.
#[derive(Clone, Debug, PartialEq)]
pub struct ByName<T>(pub Vec<(String, T)>);

impl<T> ByName<T> {
    pub fn get(&self, key: &str) -> Option<&T> {
        self.0.iter().find(|(k, _)| k == key).map(|(_, v)| v)
    }

    pub fn iter(&self) -> impl Iterator<Item = (&String, &T)> {
        self.0.iter().map(|(k, v)| (k, v))
    }

    pub fn len(&self) -> usize {
        self.0.len()
    }

    pub fn is_empty(&self) -> bool {
        self.0.is_empty()
    }
}

impl<T> FromIterator<(String, T)> for ByName<T> {
    fn from_iter<I: IntoIterator<Item = (String, T)>>(it: I) -> Self {
        Self(it.into_iter().collect())
    }
}

impl<T: Serialize> Serialize for ByName<T> {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.collect_map(self.iter())
    }
}

/// What one replica of one law gave.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sample {
    /// The largest per-joint RMS tracking error, rad: the maximum of `summary.json`'s `rms_rad`.
    pub rms_max_rad: f64,
    /// The largest per-joint max |e|, rad.
    pub max_err_rad: f64,
    /// Ticks whose reply did not act (late, skipped, missed).
    pub misses: u64,
    /// Intervals the drives clamped.
    pub clamps: u64,
    /// The largest per-joint max |τ|, N m.
    pub max_tau_nm: f64,
    /// The largest per-joint total variation of τ, N m (how much the command moved).
    pub torque_tv_nm: f64,
    /// The largest per-joint share of τ's energy above the chattering cut-off (HF share).
    pub hf_share: f64,
    pub status: RunStatus,
}

impl Sample {
    pub fn of(m: &LawMetrics, misses: u64) -> Self {
        Self {
            rms_max_rad: deltaloop_runner::replay::max_rms(m),
            max_err_rad: m.max_abs_err_rad.into_iter().fold(0.0, f64::max),
            misses,
            clamps: m.clamp_count,
            max_tau_nm: m.max_abs_tau_nm.into_iter().fold(0.0, f64::max),
            torque_tv_nm: m.torque_tv_nm.into_iter().fold(0.0, f64::max),
            hf_share: m.hf_torque_share.into_iter().fold(0.0, f64::max),
            status: m.status,
        }
    }
}

/// A distribution over replicas: its median and 2.5–97.5 % band (type 7), and its mean with the
/// mean's 95 % confidence interval (Student t).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Dist {
    pub mean: f64,
    /// Null for one replica.
    pub ci95: Option<[f64; 2]>,
    pub p2_5: f64,
    pub p50: f64,
    pub p97_5: f64,
}

impl Dist {
    /// None when `xs` is empty.
    pub fn of(xs: &[f64]) -> Option<Self> {
        let i = Interval::of(xs)?;
        let mut v: Vec<f64> = xs.iter().copied().filter(|x| x.is_finite()).collect();
        Some(Self {
            mean: i.mean,
            ci95: (i.n > 1).then_some([i.ci95_lo, i.ci95_hi]),
            p2_5: percentile_type7(&mut v, 0.025),
            p50: percentile_type7(&mut v, 0.5),
            p97_5: percentile_type7(&mut v, 0.975),
        })
    }

    /// Whether `x` lies in the 2.5–97.5 % band.
    pub fn covers(&self, x: f64) -> bool {
        (self.p2_5..=self.p97_5).contains(&x)
    }
}

/// One metric of one law over the replicas: each replica's value and their distribution.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Metric {
    /// In replica order (replica r meets the same latencies in every law); null for a replica
    /// that diverged or faulted.
    pub values: Vec<Option<f64>>,
    /// Over the replicas that completed (none: no key).
    #[serde(flatten)]
    pub dist: Option<Dist>,
}

impl Metric {
    fn of(samples: &[&Sample], f: fn(&Sample) -> f64) -> Self {
        let values: Vec<Option<f64>> = samples
            .iter()
            .map(|s| (s.status == RunStatus::Ok).then(|| f(s)))
            .collect();
        let done: Vec<f64> = values.iter().flatten().copied().collect();
        Self {
            dist: Dist::of(&done),
            values,
        }
    }
}

/// One law at one scale.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct LawOut {
    pub replicas: u64,
    /// Replicas that ran every tick; the distributions below are over them.
    pub completed: u64,
    /// Shares of the replicas the divergence rule ended, and that a fault ended (the plant
    /// stopped a loop whose replies missed `faults.controller_silence_ticks` in a row).
    pub diverged_share: f64,
    pub faulted_share: f64,
    /// Max over joints of `rms_rad`, rad.
    pub rms_max_rad: Metric,
    /// Max over joints of `max_abs_err_rad`, rad.
    pub max_err_rad: Metric,
    /// Ticks whose reply did not act.
    pub misses: Metric,
    /// Intervals the drives clamped.
    pub clamps: Metric,
    /// Max over joints of `max_abs_tau_nm`, N m.
    pub max_tau_nm: Metric,
    /// Max over joints of `torque_tv_nm`, N m.
    pub torque_tv_nm: Metric,
    /// Max over joints of `hf_torque_share`.
    pub hf_share: Metric,
}

impl LawOut {
    fn of(samples: &[&Sample]) -> Self {
        let n = samples.len() as u64;
        let share = |st: fn(RunStatus) -> bool| {
            samples.iter().filter(|s| st(s.status)).count() as f64 / n.max(1) as f64
        };
        Self {
            replicas: n,
            completed: samples.iter().filter(|s| s.status == RunStatus::Ok).count() as u64,
            diverged_share: share(|s| s == RunStatus::Diverged),
            faulted_share: share(|s| s != RunStatus::Diverged && s != RunStatus::Ok),
            rms_max_rad: Metric::of(samples, |s| s.rms_max_rad),
            max_err_rad: Metric::of(samples, |s| s.max_err_rad),
            misses: Metric::of(samples, |s| s.misses as f64),
            clamps: Metric::of(samples, |s| s.clamps as f64),
            max_tau_nm: Metric::of(samples, |s| s.max_tau_nm),
            torque_tv_nm: Metric::of(samples, |s| s.torque_tv_nm),
            hf_share: Metric::of(samples, |s| s.hf_share),
        }
    }
}

/// One `--latency` source as the output names it.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct SourceOut {
    pub path: String,
    pub kind: String,
    /// Latencies (ticks) it holds.
    pub ticks: u64,
}

/// The pooled latencies the replicas drew from.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct LatencyOut {
    pub sources: Vec<SourceOut>,
    /// `block-bootstrap`, `independent` or `as-recorded`.
    pub draw: String,
    /// The bootstrap's block, ticks (block bootstrap only).
    pub block_ticks: Option<usize>,
    pub ticks: u64,
    /// Percentiles of the pooled replies' latencies (type 7), µs.
    pub p50_us: Option<f64>,
    pub p99_us: Option<f64>,
    pub p99_9_us: Option<f64>,
    pub max_us: Option<f64>,
    /// Share of the pooled ticks whose reply would not act at scale 1: recorded late, skipped or
    /// missed, or later than the budget.
    pub miss_share: f64,
    pub budget_us: f64,
    /// Misses in a row after which the plant stops the loop (`faults.controller_silence_ticks`):
    /// the replica then ends with the controller-silence fault.
    pub controller_silence_ticks: u32,
}

/// Speed: the replicas' wall time against one in-process run of each law timed in the same
/// invocation.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct TimingOut {
    pub wall_s: f64,
    pub threads: usize,
    /// One in-process run (every reply at once) of each law, s.
    pub one_run_s: ByName<f64>,
    /// wall_s ÷ (replicas × scales × Σ one_run_s ÷ threads): 1 is a perfect parallel speed-up
    /// at no cost per replica.
    pub ratio: f64,
}

/// `whatif.json`.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct WhatIfJson {
    pub config: String,
    pub scenario: String,
    pub command: String,
    pub replicas: u64,
    /// Seeds the latency draws only (sensor noise keeps the scenario's seed).
    pub seed: u64,
    pub latency: LatencyOut,
    /// Per law (as in `--law`) at the latencies as measured (scale 1).
    pub laws: ByName<LawOut>,
    /// Each two laws at scale 1, replica by replica (`--law`'s order: the first against each
    /// later one).
    pub pairs: Vec<super::pairs::Pair>,
    /// The max-joint RMS of each law's in-process run with every reply at once, rad.
    pub ideal_rms_max_rad: ByName<f64>,
    /// Per scale (the latencies multiplied by it; `--scale`), per law; absent without --scale.
    pub scales: Option<ByName<ByName<LawOut>>>,
    pub timing: TimingOut,
}

/// What [`summarize`] reads.
pub struct Inputs<'a> {
    pub study: &'a Study,
    pub config_path: &'a Path,
    pub command: &'a str,
    pub sources: &'a [Source],
    pub model: Model,
    pub pool: &'a Pool,
    pub seed: u64,
    pub replicas: u64,
    pub laws: &'a [Law],
    pub scales: &'a [f64],
    /// In the jobs' order: scale, replica, law.
    pub samples: &'a [Sample],
    pub ideal: &'a [f64],
    pub one_run_s: &'a [f64],
    pub wall_s: f64,
    pub threads: usize,
}

/// The key of a scale in `scales` and its `traces/x<key>` folder: its shortest decimal form
/// (`0.5`, `2`), or its exponent form where that is long (`1e-300`; regression: a 300-character
/// folder name).
pub fn scale_key(s: f64) -> String {
    let plain = format!("{s}");
    if plain.len() <= 12 {
        plain
    } else {
        format!("{s:e}")
    }
}

/// The samples of law `l` of `laws` laws at scale `s`, replica by replica: `samples` is in the
/// jobs' order (scale, replica, law).
pub fn of_law(
    samples: &[Sample],
    laws: usize,
    replicas: usize,
    s: usize,
    l: usize,
) -> impl Iterator<Item = &Sample> {
    (0..replicas).map(move |r| &samples[(s * replicas + r) * laws + l])
}

/// Where scale 1 (the latencies as measured, always run) is in `scales`.
pub fn as_measured(scales: &[f64]) -> usize {
    scales.iter().position(|&s| s == 1.0).unwrap_or(0)
}

pub fn summarize(i: Inputs<'_>) -> WhatIfJson {
    let per = |s: usize| -> ByName<LawOut> {
        i.laws
            .iter()
            .enumerate()
            .map(|(l, law)| {
                let mine: Vec<&Sample> =
                    of_law(i.samples, i.laws.len(), i.replicas as usize, s, l).collect();
                (law.to_string(), LawOut::of(&mine))
            })
            .collect()
    };
    let one = as_measured(i.scales);
    let scales = (i.scales.len() > 1).then(|| {
        (0..i.scales.len())
            .map(|s| (scale_key(i.scales[s]), per(s)))
            .collect()
    });
    let by_law = |v: &[f64]| -> ByName<f64> {
        i.laws
            .iter()
            .zip(v)
            .map(|(l, &x)| (l.to_string(), x))
            .collect()
    };
    let serial = i.one_run_s.iter().sum::<f64>() * i.replicas as f64 * i.scales.len() as f64
        / i.threads.max(1) as f64;
    WhatIfJson {
        config: i.config_path.display().to_string(),
        scenario: i.study.config.name.clone(),
        command: i.command.to_string(),
        replicas: i.replicas,
        seed: i.seed,
        latency: latency_out(&i),
        pairs: super::pairs::all(
            &per(one)
                .iter()
                .map(|(l, o)| (l.clone(), o.rms_max_rad.values.clone()))
                .collect::<Vec<_>>(),
            i.seed,
        ),
        laws: per(one),
        ideal_rms_max_rad: by_law(i.ideal),
        scales,
        timing: TimingOut {
            wall_s: i.wall_s,
            threads: i.threads,
            one_run_s: by_law(i.one_run_s),
            ratio: i.wall_s / serial,
        },
    }
}

fn latency_out(i: &Inputs<'_>) -> LatencyOut {
    let budget_ns = u64::from(i.study.config.loop_.torque_budget_us) * 1000;
    let (mut ticks, mut missed) = (0u64, 0u64);
    let mut replies: Vec<(u64, u64)> = Vec::new();
    for (t, c) in i.pool.distribution() {
        ticks += c;
        match t {
            ReplyOutcome::Applied(l) => {
                replies.push((l, c));
                if l > budget_ns {
                    missed += c;
                }
            }
            ReplyOutcome::Late | ReplyOutcome::Skipped | ReplyOutcome::Missed => missed += c,
        }
    }
    let n: u64 = replies.iter().map(|r| r.1).sum();
    // Type 7 over the weighted values: the order statistic at rank (n − 1)·p, interpolated.
    let at = |p: f64| -> Option<f64> {
        if n == 0 {
            return None;
        }
        let h = (n - 1) as f64 * p;
        let value = |rank: u64| {
            let mut seen = 0;
            for &(v, c) in &replies {
                seen += c;
                if rank < seen {
                    return v as f64;
                }
            }
            replies.last().map_or(f64::NAN, |r| r.0 as f64)
        };
        let (lo, hi) = (value(h.floor() as u64), value(h.ceil() as u64));
        Some((lo + (h - h.floor()) * (hi - lo)) / 1e3)
    };
    LatencyOut {
        sources: i
            .sources
            .iter()
            .map(|s| SourceOut {
                path: s.path.display().to_string(),
                kind: s.kind.name().to_string(),
                ticks: s.ticks,
            })
            .collect(),
        draw: i.model.name().to_string(),
        block_ticks: match i.model {
            Model::Block { ticks } => Some(ticks),
            _ => None,
        },
        ticks,
        p50_us: at(0.5),
        p99_us: at(0.99),
        p99_9_us: at(0.999),
        max_us: replies.last().map(|r| r.0 as f64 / 1e3),
        miss_share: missed as f64 / ticks.max(1) as f64,
        budget_us: budget_ns as f64 / 1e3,
        controller_silence_ticks: i.study.config.faults.controller_silence_ticks,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn equal_replicas_give_their_value_to_the_bit_and_a_band_covers() {
        let x = 7.123456789e-8;
        let d = Dist::of(&[x; 200]).unwrap();
        assert_eq!((d.p2_5, d.p50, d.p97_5), (x, x, x));
        let d = Dist::of(&(1..=1000).map(f64::from).collect::<Vec<_>>()).unwrap();
        assert!((d.p50 - 500.5).abs() < 1e-9 && (d.p2_5 - 25.975).abs() < 1e-9);
        assert!(d.covers(26.0) && !d.covers(25.0) && !d.covers(976.0));
        let [lo, hi] = d.ci95.unwrap();
        assert!(lo < 500.5 && 500.5 < hi && hi - lo < 40.0);
        assert_eq!(Dist::of(&[3.0]).unwrap().ci95, None);
        assert_eq!(Dist::of(&[]), None);
    }
}
