//! One point of a sweep: its config, its run (through the same code as `deltaloop run`), and
//! its row of `sweep.csv` with the status the run ended in.

use super::schema::{Job, SweepFile};
use anyhow::{Context, Result};
use deltaloop_config::PathKind;
use deltaloop_config::{Compensation, Law, LawVariant, LoopMode, Preset, RunConfig};
use deltaloop_runner::Ran;
use deltaloop_runner::inproc;
use deltaloop_runner::lawrun::Keep;
use deltaloop_study::Study;
use deltaloop_study::record::RunStatus;
use deltaloop_study::record::metrics::LawMetrics;
use deltaloop_study::record::stats;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// One grid point's result: a row of `sweep.csv`.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Row {
    /// The point's id in the plan (see [`super::plan::Plan`]).
    pub point: String,
    pub scenario: PathKind,
    pub preset: Preset,
    /// The law, `<law>+pred` when it ran compensated (`controller.compensate = "predict"`).
    pub law: LawVariant,
    pub mode: LoopMode,
    pub tde_delay_samples: u32,
    pub transport_delay_samples: u32,
    /// The sub-tick transport delay, µs (the delay D is d·Ts plus this).
    #[serde(with = "nan_empty")]
    pub transport_delay_us: f64,
    /// The effective estimation delay L_eff/Ts = ℓ + D/Ts, ticks.
    #[serde(with = "nan_empty")]
    pub effective_delay_ticks: f64,
    pub compute_delay_us: u32,
    /// How the point ended: the run's [`RunStatus`] (`error`: the point could not run).
    pub status: RunStatus,
    /// Set only for `diverged`.
    pub diverged_at_tick: Option<u64>,
    /// Why, for every status but `ok`.
    pub reason: String,
    /// Max over joints of the RMS joint error, rad.
    #[serde(with = "nan_empty")]
    pub rms_rad: f64,
    #[serde(with = "nan_empty")]
    pub max_abs_err_rad: f64,
    #[serde(with = "nan_empty")]
    pub task_rms_mm: f64,
    /// Max over joints of the TDE error RMS, rad/s².
    #[serde(with = "nan_empty")]
    pub tde_err_rms: f64,
    /// Max over joints of δ_N max and of its 99.9th percentile, rad/s³.
    #[serde(with = "nan_empty")]
    pub delta_n_max: f64,
    #[serde(with = "nan_empty")]
    pub delta_n_p999: f64,
    #[serde(with = "nan_empty")]
    pub k2_required: f64,
    pub eq43_holds: bool,
    #[serde(with = "nan_empty")]
    pub hf_torque_share: f64,
    pub clamp_count: u64,
    pub deadline_misses: Option<u64>,
    /// Empty when the run has no round-trip sample (never 0 for "no data").
    pub round_trip_p999_us: Option<f64>,
    /// Realtime points: max-joint RMS over that of the same config with ideal timing
    /// (in-process, same seed); over repeats, the geometric mean; NaN for the other points.
    #[serde(with = "nan_empty")]
    pub latency_cost: f64,
    /// Runs this row summarises: sensor-noise seeds `seed`, `seed` + 1, …; the metrics above
    /// are their means over the runs that ended `ok` (`repeats_ok` of them).
    pub repeats: u32,
    pub repeats_ok: u32,
    pub seed: u64,
    /// Sample standard deviation and t-based 95 % confidence interval of the mean
    /// ([`deltaloop_study::record::stats::Interval`]) of `rms_rad` over the repeats; NaN below 2.
    #[serde(with = "nan_empty")]
    pub rms_rad_std: f64,
    #[serde(with = "nan_empty")]
    pub rms_rad_ci95_lo: f64,
    #[serde(with = "nan_empty")]
    pub rms_rad_ci95_hi: f64,
    /// The same for `max_abs_err_rad`.
    #[serde(with = "nan_empty")]
    pub max_abs_err_rad_std: f64,
    #[serde(with = "nan_empty")]
    pub max_abs_err_rad_ci95_lo: f64,
    #[serde(with = "nan_empty")]
    pub max_abs_err_rad_ci95_hi: f64,
    /// The same for `tde_err_rms`.
    #[serde(with = "nan_empty")]
    pub tde_err_rms_std: f64,
    #[serde(with = "nan_empty")]
    pub tde_err_rms_ci95_lo: f64,
    #[serde(with = "nan_empty")]
    pub tde_err_rms_ci95_hi: f64,
    /// For `latency_cost`, a ratio: the standard deviation of its logarithm and the 95 % CI of
    /// its geometric mean ([`deltaloop_study::record::stats::RatioInterval`]).
    #[serde(with = "nan_empty")]
    pub latency_cost_log_std: f64,
    #[serde(with = "nan_empty")]
    pub latency_cost_ci95_lo: f64,
    #[serde(with = "nan_empty")]
    pub latency_cost_ci95_hi: f64,
    /// Relative change of `rms_rad`, `max_abs_err_rad` and `tde_err_rms` under the round-off
    /// twin of the first seed's run (see [`deltaloop_study::record::sensitivity`]); NaN without a twin
    /// (realtime points, `sensitivity = false`).
    #[serde(with = "nan_empty")]
    pub rms_rad_roundoff: f64,
    #[serde(with = "nan_empty")]
    pub max_abs_err_rad_roundoff: f64,
    #[serde(with = "nan_empty")]
    pub tde_err_rms_roundoff: f64,
    /// Points of the `link_delay_us` axis only (empty for the others): the emulated delay, µs
    /// each direction.
    #[serde(default)]
    pub link_delay_us: Option<f64>,
    /// The link's round trip (the round trip less the far host's residence), p50, µs.
    #[serde(default)]
    pub link_rtt_p50_us: Option<f64>,
    /// The median arrival A_k − t_k of the commands the plant applied, µs.
    #[serde(default)]
    pub median_arrival_us: Option<f64>,
    /// Max-joint RMS of the same config in-process with `transport_delay_us` =
    /// `median_arrival_us`, same seed: the delay injected deterministically. Over repeats, means.
    #[serde(default)]
    pub injected_rms_rad: Option<f64>,
    /// Why the realtime run is not a fair twin of the injected one (empty: it is): more than
    /// [`LINK_MAX_MISS_SHARE`] of its ticks missed, a burst of [`LINK_MAX_MISS_BURST`] or more
    /// missed in a row, or the plant paused its clock or once woke a tick or more late (the machine stalled the
    /// loop).
    #[serde(default)]
    pub link_disturbed: Option<String>,
    /// Max-joint RMS of the realtime run's in-process replay: the same run with each reply acting
    /// at its own measured arrival, deterministic (`deltaloop replay`). Against
    /// `injected_rms_rad` it says whether one constant delay explains the link's effect, also
    /// when the realtime run itself was disturbed. Over repeats, means.
    #[serde(default)]
    pub replay_rms_rad: Option<f64>,
    /// Process points: the longest run of consecutive missed ticks (over repeats, the largest).
    #[serde(default)]
    pub max_consecutive_misses: Option<u64>,
}

/// A metric that may have no value (NaN in memory: a single repeat has no spread, an in-process
/// point no latency cost) as an empty cell of `sweep.csv` (null in JSON), never the text `NaN`;
/// an empty cell, or a `NaN` of an older shard, reads back as NaN.
mod nan_empty {
    use serde::{Deserialize, Deserializer, Serializer};

    pub fn serialize<S: Serializer>(x: &f64, s: S) -> Result<S::Ok, S::Error> {
        if x.is_nan() {
            s.serialize_none()
        } else {
            s.serialize_some(x)
        }
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
        Ok(Option::<f64>::deserialize(d)?.unwrap_or(f64::NAN))
    }
}

/// The share of missed ticks above which a link point's realtime run is disturbed (see
/// [`Row::link_disturbed`]).
pub const LINK_MAX_MISS_SHARE: f64 = deltaloop_timing::MAX_MISS_SHARE;

/// The burst of consecutive missed ticks from which a link point's realtime run is disturbed.
pub const LINK_MAX_MISS_BURST: u64 = deltaloop_timing::MAX_MISS_BURST;

/// What a link point measured besides its metrics (see [`Row::link_delay_us`]).
#[derive(Debug, Clone, Default)]
struct LinkResult {
    rtt_p50_us: Option<f64>,
    median_arrival_us: Option<f64>,
    injected_rms_rad: Option<f64>,
    replay_rms_rad: Option<f64>,
    disturbed: Option<String>,
    /// Why the injected twin gave no RMS (it failed, or did not complete).
    twin_failed: Option<String>,
}

impl Row {
    /// Whether the row is a point of the ℓ × d grid: not of the realtime axes (compute delay,
    /// link delay) nor of the sub-tick delay axis.
    pub fn on_grid(&self) -> bool {
        self.mode != LoopMode::Realtime && self.transport_delay_us == 0.0
    }

    /// Whether the row is a result (every status but `interrupted`: a point cut short by
    /// Ctrl-C / SIGTERM measured nothing complete).
    pub fn is_result(&self) -> bool {
        self.status != RunStatus::Interrupted
    }
}

/// A metric read off a row.
pub(super) type Metric = fn(&Row) -> f64;

fn maxj(v: [f64; 3]) -> f64 {
    v.into_iter().fold(0.0, f64::max)
}

/// Status and reason of a point (see [`Row::status`]): the run's own (see
/// [`RunEnd::status`](deltaloop_study::record::RunEnd::status)), or `error` with the error.
fn status(m: Option<&LawMetrics>, err: Option<&str>) -> (RunStatus, String) {
    match (m, err) {
        (Some(m), None) => (m.status, m.reason.clone().unwrap_or_default()),
        (Some(_), Some(e)) => (RunStatus::Error, e.to_string()),
        (None, e) => {
            let e = e.filter(|e| !e.is_empty()).unwrap_or("no result");
            (RunStatus::Error, e.to_string())
        }
    }
}

fn row(
    job: &Job,
    ts_s: f64,
    mode: LoopMode,
    m: Option<&LawMetrics>,
    err: Option<String>,
    timing: Option<&deltaloop_timing::TimingSummary>,
) -> Row {
    let (status, reason) = status(m, err.as_deref());
    // A point that did not finish carries no metrics: nothing in it is a result.
    let (m, timing) = if status == RunStatus::Interrupted {
        (None, None)
    } else {
        (m, timing)
    };
    let nan = f64::NAN;
    Row {
        point: String::new(),
        scenario: job.scenario,
        preset: job.preset,
        law: job.variant(),
        mode,
        tde_delay_samples: job.ell,
        transport_delay_samples: job.d,
        transport_delay_us: job.kind.transport_us(),
        effective_delay_ticks: f64::from(job.ell)
            + f64::from(job.d)
            + job.kind.transport_us() * 1e-6 / ts_s,
        compute_delay_us: job.kind.compute_us(),
        status,
        diverged_at_tick: m
            .and_then(|m| m.diverged_at_tick)
            .filter(|_| status == RunStatus::Diverged),
        reason,
        rms_rad: m.map_or(nan, |m| maxj(m.rms_rad)),
        max_abs_err_rad: m.map_or(nan, |m| maxj(m.max_abs_err_rad)),
        task_rms_mm: m.map_or(nan, |m| m.task_rms_mm),
        tde_err_rms: m.and_then(|m| m.tde_err_rms).map_or(nan, maxj),
        delta_n_max: m.and_then(|m| m.delta_n_max).map_or(nan, maxj),
        delta_n_p999: m.and_then(|m| m.delta_n_p999).map_or(nan, maxj),
        k2_required: m.and_then(|m| m.k2_required).unwrap_or(nan),
        eq43_holds: m.and_then(|m| m.eq43_holds).unwrap_or(false),
        hf_torque_share: m.map_or(nan, |m| maxj(m.hf_torque_share)),
        clamp_count: m.map_or(0, |m| m.clamp_count),
        deadline_misses: timing.map(|t| t.deadline_misses),
        round_trip_p999_us: timing
            .filter(|t| t.round_trip.count > 0)
            .map(|t| t.round_trip.p999_us),
        latency_cost: nan,
        repeats: 1,
        repeats_ok: u32::from(status == RunStatus::Ok),
        seed: 0,
        rms_rad_std: nan,
        rms_rad_ci95_lo: nan,
        rms_rad_ci95_hi: nan,
        max_abs_err_rad_std: nan,
        max_abs_err_rad_ci95_lo: nan,
        max_abs_err_rad_ci95_hi: nan,
        tde_err_rms_std: nan,
        tde_err_rms_ci95_lo: nan,
        tde_err_rms_ci95_hi: nan,
        latency_cost_log_std: nan,
        latency_cost_ci95_lo: nan,
        latency_cost_ci95_hi: nan,
        rms_rad_roundoff: m.and_then(|m| m.sensitivity).map_or(nan, |x| x.rms_rel),
        max_abs_err_rad_roundoff: m.and_then(|m| m.sensitivity).map_or(nan, |x| x.max_err_rel),
        tde_err_rms_roundoff: m
            .and_then(|m| m.sensitivity)
            .and_then(|x| x.tde_rel)
            .unwrap_or(nan),
        link_delay_us: job.kind.link().map(|l| l.delay_us),
        link_rtt_p50_us: None,
        median_arrival_us: None,
        injected_rms_rad: None,
        link_disturbed: None,
        replay_rms_rad: None,
        max_consecutive_misses: timing.map(|t| t.max_consecutive_misses),
    }
}

/// One row out of a point's repeats (in seed order; at least one). Status `ok` when some repeat
/// ended `ok` (the others are counted, `repeats_ok` < `repeats`, and named in the reason), else
/// the first repeat's status; each metric the mean over the repeats that ended `ok`, with the
/// standard deviation and 95 % CI of the headline ones (the latency cost, a ratio: geometric mean
/// and log-space interval); counts and round-trip tails the largest; the round-off spreads of the
/// first repeat that ended `ok`.
fn summarise(reps: Vec<Row>) -> Row {
    let ok: Vec<&Row> = reps.iter().filter(|r| r.status == RunStatus::Ok).collect();
    let first_bad = reps.iter().find(|r| r.status != RunStatus::Ok);
    let n = reps.len() as u32;
    let mut out = ok.first().copied().unwrap_or(&reps[0]).clone();
    if n == 1 {
        return out;
    }
    if ok.is_empty() {
        out.reason = format!("every seed; seed {}: {}", out.seed, out.reason);
    } else if let Some(b) = first_bad {
        let bad = reps.len() - ok.len();
        out.reason = format!(
            "{bad} of {n} seeds did not end ok (left out of the means); seed {} {}: {}",
            b.seed, b.status, b.reason
        );
    }
    out.seed = reps[0].seed;
    let mean = |f: Metric| {
        stats::Interval::of(&ok.iter().map(|r| f(r)).collect::<Vec<_>>())
            .map_or(f64::NAN, |i| i.mean)
    };
    let ci = |f: Metric| stats::Interval::of(&ok.iter().map(|r| f(r)).collect::<Vec<_>>());
    let nan3 = (f64::NAN, f64::NAN, f64::NAN);
    let spread = |i: Option<stats::Interval>| i.map_or(nan3, |i| (i.std, i.ci95_lo, i.ci95_hi));
    out.rms_rad = mean(|r| r.rms_rad);
    out.max_abs_err_rad = mean(|r| r.max_abs_err_rad);
    out.task_rms_mm = mean(|r| r.task_rms_mm);
    out.tde_err_rms = mean(|r| r.tde_err_rms);
    out.delta_n_max = mean(|r| r.delta_n_max);
    out.delta_n_p999 = mean(|r| r.delta_n_p999);
    out.k2_required = mean(|r| r.k2_required);
    out.hf_torque_share = mean(|r| r.hf_torque_share);
    let cost = stats::RatioInterval::of(&ok.iter().map(|r| r.latency_cost).collect::<Vec<_>>());
    out.latency_cost = cost.map_or(f64::NAN, |c| c.geo_mean);
    let mean_of = |f: fn(&Row) -> Option<f64>| {
        let v: Vec<f64> = ok.iter().filter_map(|r| f(r)).collect();
        (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64)
    };
    out.link_rtt_p50_us = mean_of(|r| r.link_rtt_p50_us);
    out.median_arrival_us = mean_of(|r| r.median_arrival_us);
    out.injected_rms_rad = mean_of(|r| r.injected_rms_rad);
    out.replay_rms_rad = mean_of(|r| r.replay_rms_rad);
    out.link_disturbed = ok.iter().find_map(|r| r.link_disturbed.clone());
    out.eq43_holds = !ok.is_empty() && ok.iter().all(|r| r.eq43_holds);
    out.clamp_count = reps.iter().map(|r| r.clamp_count).max().unwrap_or(0);
    out.deadline_misses = reps.iter().filter_map(|r| r.deadline_misses).max();
    out.max_consecutive_misses = reps.iter().filter_map(|r| r.max_consecutive_misses).max();
    out.round_trip_p999_us = reps
        .iter()
        .filter_map(|r| r.round_trip_p999_us)
        .reduce(f64::max);
    out.repeats = n;
    out.repeats_ok = ok.len() as u32;
    (out.rms_rad_std, out.rms_rad_ci95_lo, out.rms_rad_ci95_hi) = spread(ci(|r| r.rms_rad));
    (
        out.max_abs_err_rad_std,
        out.max_abs_err_rad_ci95_lo,
        out.max_abs_err_rad_ci95_hi,
    ) = spread(ci(|r| r.max_abs_err_rad));
    (
        out.tde_err_rms_std,
        out.tde_err_rms_ci95_lo,
        out.tde_err_rms_ci95_hi,
    ) = spread(ci(|r| r.tde_err_rms));
    (
        out.latency_cost_log_std,
        out.latency_cost_ci95_lo,
        out.latency_cost_ci95_hi,
    ) = cost.map_or(nan3, |c| (c.log_std, c.ci95_lo, c.ci95_hi));
    out
}

/// The config of one grid point: the base with the axes applied, validated.
pub(super) fn point_config(base: &RunConfig, job: &Job) -> Result<RunConfig> {
    let mut c = base.clone();
    c.name = format!(
        "{}-{}-{}{}-l{}-d{}-u{}-c{}{}",
        job.scenario.name(),
        job.preset.name(),
        job.law,
        match job.compensate {
            Compensation::None => "",
            Compensation::Predict => "-pred",
        },
        job.ell,
        job.d,
        (job.kind.transport_us() * 1e3).round(),
        job.kind.compute_us(),
        job.kind.link().map_or(String::new(), |l| format!(
            "-link{}",
            // + 0.0: −0 µs is the 0 µs point (not a folder `link-0`).
            (l.delay_us * 1e3).round() + 0.0
        ))
    )
    .to_lowercase();
    if job.kind.link().is_some() && !c.controller.command.is_empty() {
        anyhow::bail!(
            "sweep key `link_delay_us` runs the built-in controller across the bridge: the base's controller.command = {:?} cannot be used with it (leave it out, or run the link axis in a sweep of its own)",
            c.controller.command.join(" ")
        );
    }
    c.scenario.path = job.scenario;
    c.scenario.segments.clear();
    // The preset axis sets the constants that differ between presets (M̄, φ); the base's other
    // constants (gains) stay as the base resolved them.
    c.controller.preset = job.preset;
    let p = deltaloop_config::ControllerParams::preset(job.preset);
    c.controller.m_bar = Some(p.m_bar);
    c.controller.phi = Some(p.phi);
    c.controller.laws = vec![job.law];
    c.controller.compensate = job.compensate;
    if job.compensate == Compensation::None {
        // What only a compensated law reads (the base's, for its `+pred` points).
        c.controller.compensate_delay_us = None;
        c.controller.compensate_delay = Default::default();
    }
    c.controller.tde_delay_samples = job.ell;
    c.controller.compute_delay_us = job.kind.compute_us();
    c.plant.transport_delay_samples = job.d;
    c.plant.transport_delay_us = job.kind.transport_us();
    c.validate()?;
    Ok(c)
}

/// Runs one point: `sw.repeats` runs with sensor-noise seeds base, base + 1, … (each a row,
/// [`summarise`]d into one), the round-off twin of the first that ends ok when
/// `sw.sensitivity` (not in realtime, not with a plant or controller command), and for a
/// realtime point the same config with ideal timing for its latency cost.
pub(super) fn run_job(sw: &SweepFile, base: &RunConfig, job: &Job, dir: &Path) -> Row {
    let seed0 = base.sensor.seed;
    // The twin repeats a run of the built-in processes only, and one that ended ok is enough.
    let mut twin =
        sw.sensitivity && base.plant.command.is_empty() && base.controller.command.is_empty();
    let reps = (0..sw.repeats.max(1))
        .map(|i| {
            let seed = seed0.wrapping_add(u64::from(i));
            let sub = (sw.repeats > 1).then(|| format!("r{i}"));
            let mut r = run_one(base, job, sw.mode, dir, seed, twin, sub.as_deref());
            twin &= r.status != RunStatus::Ok;
            r.seed = seed;
            r
        })
        .collect();
    summarise(reps)
}

/// One run of a point with sensor seed `seed`; `twin`: with its round-off twin; `sub`: the
/// repeat's own sub-folder of the point's folder (process modes).
fn run_one(
    base: &RunConfig,
    job: &Job,
    mode: LoopMode,
    dir: &Path,
    seed: u64,
    twin: bool,
    sub: Option<&str>,
) -> Row {
    let ts_s = base.loop_.ts_s;
    let mode = if job.kind.realtime() {
        LoopMode::Realtime
    } else {
        mode
    };
    let attempt = || -> Result<Attempt> {
        let mut cfg = point_config(base, job)?;
        cfg.sensor.seed = seed;
        let mut pdir = dir.join("points").join(&cfg.name);
        if let Some(s) = sub {
            pdir = pdir.join(s);
        }
        if mode.is_process() {
            std::fs::create_dir_all(&pdir)?;
        }
        // A link point: the far side on this host's loopback, stopped and its root removed
        // when `far` is dropped (also on an error or Ctrl-C).
        let far = job
            .kind
            .link()
            .map(|l| link_far(&mut cfg, l, seed, &pdir))
            .transpose()?;
        let study = Study::new(cfg).context("reference")?;
        if mode.is_process() {
            deltaloop_report::write_text(
                &pdir.join("config.toml"),
                &study.config.to_toml_string(),
            )?;
        }
        let mut link = LinkResult::default();
        // A link point keeps its trace: its replay re-runs it from the recorded arrivals.
        let keep = Keep {
            trace: job
                .kind
                .link()
                .map(|_| deltaloop_report::trace_part(&pdir, job.law)),
            ..Keep::default()
        };
        let (mut m, timing) =
            match deltaloop_runner::run_law(&study, job.law, mode, &pdir, &keep, None)? {
                Ran::Process(r) => {
                    let t = r.timing.summary();
                    if job.kind.link().is_some() {
                        let h = &r.timing.arrival.hist;
                        link.median_arrival_us =
                            (!h.is_empty()).then(|| h.value_at_quantile(0.5) as f64 / 1e3);
                        link.rtt_p50_us = t.link_rtt.as_ref().map(|p| p.p50_us);
                        link.disturbed = t.disturbance.clone();
                    }
                    (r.run.metrics, Some(t))
                }
                Ran::Inproc(run) => (run.metrics, None),
            };
        if let Some(far) = far {
            far.finish(std::time::Duration::from_secs(2));
        }
        if job.kind.link().is_some()
            && m.status == RunStatus::Ok
            && let Some(arrival_us) = link.median_arrival_us
        {
            injected_twin(base, job, seed, arrival_us, &mut link);
        }
        if job.kind.link().is_some() && m.status == RunStatus::Ok {
            link.replay_rms_rad = replayed_rms(&pdir, job.law);
        }
        if twin && mode != LoopMode::Realtime && m.status.is_physical() {
            let twins = inproc::run_twins_of(&study, job.law)?;
            m.sensitivity = m.against_twins(&twins);
        }
        let cost = if mode == LoopMode::Realtime && m.status == RunStatus::Ok {
            let ideal = inproc::run_law(&study, job.law, &Keep::default())?;
            maxj(m.rms_rad) / maxj(ideal.metrics.rms_rad)
        } else {
            f64::NAN
        };
        Ok((m, timing, cost, link))
    };
    let attempt = std::panic::catch_unwind(std::panic::AssertUnwindSafe(attempt));
    row_of(job, ts_s, mode, attempt)
}

/// The in-process twin of a link point: the same point with its median arrival (which already
/// holds the point's d·Ts: the plant reports A_k − t_k) injected as one constant delay
/// (regression: it kept d samples too). A twin that failed leaves the realtime result whole and
/// says why in `link`.
fn injected_twin(base: &RunConfig, job: &Job, seed: u64, arrival_us: f64, link: &mut LinkResult) {
    let twin = || -> Result<LawMetrics> {
        let mut c = point_config(base, job)?;
        c.sensor.seed = seed;
        c.plant.transport_delay_samples = 0;
        c.plant.transport_delay_us = arrival_us;
        c.validate()?;
        Ok(inproc::run_law(&Study::new(c)?, job.law, &Keep::default())?.metrics)
    };
    match twin() {
        Ok(t) if t.status == RunStatus::Ok => link.injected_rms_rad = Some(maxj(t.rms_rad)),
        Ok(t) => {
            link.twin_failed = Some(format!(
                "injected twin {}: {}",
                t.status,
                t.reason.as_deref().unwrap_or("")
            ))
        }
        Err(e) => link.twin_failed = Some(format!("injected twin: {e:#}")),
    }
}

/// The max-joint RMS of the in-process replay of the link point in `pdir` (its trace joined,
/// then re-run from the recorded arrivals into `pdir/replay`); None if it cannot be replayed.
fn replayed_rms(pdir: &Path, law: Law) -> Option<f64> {
    deltaloop_report::join_trace(pdir, &[law]).ok()?;
    let (_, runs) = deltaloop_runner::replay::replay(pdir, &pdir.join("replay")).ok()?;
    let r = runs.into_iter().next()?;
    (r.metrics.status == RunStatus::Ok).then(|| maxj(r.metrics.rms_rad))
}

/// What one attempt at a point gives, as `run_one` computes it: the metrics, the loop timing,
/// the latency cost and the link's figures.
type Attempt = (
    LawMetrics,
    Option<deltaloop_timing::TimingSummary>,
    f64,
    LinkResult,
);

/// The point's row from its attempt: its figures, or the error or panic that ended it.
fn row_of(
    job: &Job,
    ts_s: f64,
    mode: LoopMode,
    attempt: std::thread::Result<Result<Attempt>>,
) -> Row {
    match attempt {
        Ok(Ok((m, t, cost, link))) => {
            let mut r = Row {
                latency_cost: cost,
                link_rtt_p50_us: link.rtt_p50_us,
                median_arrival_us: link.median_arrival_us,
                injected_rms_rad: link.injected_rms_rad,
                replay_rms_rad: link.replay_rms_rad,
                link_disturbed: link.disturbed,
                ..row(job, ts_s, mode, Some(&m), None, t.as_ref())
            };
            if let Some(why) = link.twin_failed {
                r.reason = why;
            }
            r
        }
        Ok(Err(e)) => row(job, ts_s, mode, None, Some(format!("{e:#}")), None),
        Err(p) => {
            let what = p
                .downcast_ref::<String>()
                .cloned()
                .or_else(|| p.downcast_ref::<&str>().map(|s| s.to_string()))
                .unwrap_or_else(|| "(no message)".into());
            row(job, ts_s, mode, None, Some(format!("panic: {what}")), None)
        }
    }
}

/// Starts the far side of link point `l` on this host's loopback and puts the near bridge in
/// `cfg`'s controller place (as `deltaloop run --controller-remote 127.0.0.1:PORT` with the
/// emulated link, seeded with the run's `seed`); the far bridge's log is `pdir/far.log`.
fn link_far(
    cfg: &mut RunConfig,
    l: super::schema::Link,
    seed: u64,
    pdir: &Path,
) -> Result<deltaloop_runner::loopback::LoopbackFar> {
    let far = deltaloop_runner::loopback::LoopbackFar::start(&pdir.join("far.log"))?;
    deltaloop_runner::join::RemoteArgs {
        controller_remote: Some(far.endpoint.clone()),
        plant_remote: None,
        emulation: deltaloop_config::LinkEmulation {
            delay_us: l.delay_us,
            jitter_us: l.jitter_us,
            loss: l.loss,
            seed,
        },
        spin_us: 0,
        path: cfg.link.as_ref().map(|l| l.path),
        link_key: None,
        quiet: true,
    }
    .apply(cfg)?;
    Ok(far)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sweep::{PointKind, report};
    use deltaloop_study::record::{Fault, FaultKind, Outcome, RunEnd};

    /// S2, matched, `tdc`, ℓ = 1, d = 0, a realtime point at a 200 µs compute delay.
    fn s2_tdc_realtime_job() -> Job {
        Job {
            scenario: PathKind::S2,
            preset: Preset::Matched,
            law: Law::Tdc,
            compensate: Compensation::None,
            ell: 1,
            d: 0,
            kind: PointKind::Compute { us: 200 },
        }
    }

    /// Repeats fold into one row: means over the `ok` repeats, the hand-computed standard
    /// deviation and t interval (rms 1, 2, 3 → mean 2, s = 1, t₀.₉₇₅,₂ = 4.302652729911275,
    /// half-width 4.302652729911275/√3 = 2.484137...), the first non-ok repeat's status named by
    /// its seed and left out, the largest counts.
    #[test]
    fn repeats_summarise_to_mean_std_and_t_interval() {
        let job = Job {
            kind: PointKind::Grid,
            ..s2_tdc_realtime_job()
        };
        let m = some_metrics();
        let mk = |rms: f64, seed: u64, clamps: u64| {
            let mut r = row(&job, 3e-4, LoopMode::Inproc, Some(&m), None, None);
            (r.rms_rad, r.seed, r.clamp_count) = (rms, seed, clamps);
            r
        };
        let mut bad = mk(f64::NAN, 13, 0);
        bad.status = RunStatus::Diverged;
        bad.reason = "|e| > 0.5 rad".into();
        let r = summarise(vec![
            mk(1.0, 10, 0),
            mk(2.0, 11, 5),
            mk(3.0, 12, 2),
            bad.clone(),
        ]);
        assert_eq!((r.repeats, r.repeats_ok, r.seed), (4, 3, 10));
        assert_eq!(r.status, RunStatus::Ok);
        assert_eq!(
            r.reason,
            "1 of 4 seeds did not end ok (left out of the means); seed 13 diverged: |e| > 0.5 rad"
        );
        // No repeat ok: the first repeat's status.
        let none = summarise(vec![bad.clone(), bad]);
        assert_eq!((none.status, none.repeats_ok), (RunStatus::Diverged, 0));
        assert_eq!((r.rms_rad, r.rms_rad_std), (2.0, 1.0));
        let half = 4.302652729911275 / 3f64.sqrt();
        assert!(
            (r.rms_rad_ci95_lo - (2.0 - half)).abs() < 1e-7,
            "{}",
            r.rms_rad_ci95_lo
        );
        assert!((r.rms_rad_ci95_hi - (2.0 + half)).abs() < 1e-7);
        assert_eq!(r.clamp_count, 5);
        // One repeat: the row as it was, no interval.
        let one = summarise(vec![mk(1.0, 10, 0)]);
        assert_eq!((one.repeats, one.rms_rad), (1, 1.0));
        assert!(one.rms_rad_std.is_nan() && one.rms_rad_ci95_lo.is_nan());
    }

    /// Regression: `repeats = 1` wrote the text `NaN` in the spread columns where the docs say
    /// a value that does not exist is an empty cell; an empty cell (or an old shard's `NaN`)
    /// reads back as no value.
    #[test]
    fn regression_a_single_repeat_leaves_its_spread_cells_empty_not_nan() {
        let job = Job {
            kind: PointKind::Grid,
            ..s2_tdc_realtime_job()
        };
        let one = summarise(vec![row(
            &job,
            3e-4,
            LoopMode::Inproc,
            Some(&some_metrics()),
            None,
            None,
        )]);
        let mut w = csv::Writer::from_writer(Vec::new());
        w.serialize(&one).unwrap();
        let text = String::from_utf8(w.into_inner().unwrap()).unwrap();
        assert!(!text.contains("NaN"), "{text}");
        let mut rd = csv::Reader::from_reader(text.as_bytes());
        let head = rd.headers().unwrap().clone();
        let rec = rd.records().next().unwrap().unwrap();
        for col in ["rms_rad_std", "rms_rad_ci95_lo", "latency_cost"] {
            let i = head.iter().position(|h| h == col).unwrap();
            assert_eq!(&rec[i], "", "{col} in {text}");
        }
        let i = head.iter().position(|h| h == "rms_rad").unwrap();
        assert!(rec[i].parse::<f64>().unwrap() > 0.0);
        // A shard of an older version wrote `NaN` there.
        let std = head.iter().position(|h| h == "rms_rad_std").unwrap();
        let old: csv::StringRecord = rec
            .iter()
            .enumerate()
            .map(|(k, c)| if k == std { "NaN" } else { c })
            .collect();
        let mut w = csv::Writer::from_writer(Vec::new());
        w.write_record(&head).unwrap();
        w.write_record(&old).unwrap();
        let old = String::from_utf8(w.into_inner().unwrap()).unwrap();
        for t in [text, old] {
            let back: Row = csv::Reader::from_reader(t.as_bytes())
                .deserialize()
                .next()
                .unwrap()
                .unwrap();
            assert!(back.rms_rad_std.is_nan() && back.rms_rad == one.rms_rad);
        }
    }

    /// Metrics of a real (short) run, to vary.
    fn some_metrics() -> LawMetrics {
        let cfg = RunConfig::from_toml_str(
            "[scenario]\npath = \"s2\"\n[controller]\nlaws = [\"tdc\"]\n",
            None,
        )
        .unwrap();
        let study = Study::new(cfg).unwrap();
        inproc::run_law(&study, Law::Tdc, &Keep::default())
            .unwrap()
            .metrics
    }

    /// `m` as if its run had ended with `outcome` and `fault`: the status fields as
    /// [`MetricsAcc::finish`](deltaloop_study::record::metrics::MetricsAcc::finish) sets them.
    fn ended(m: &LawMetrics, outcome: Outcome, fault: Option<Fault>) -> LawMetrics {
        let end = RunEnd {
            law: m.law,
            records: m.ticks + 1,
            lost_ticks: 0,
            first_lost: None,
            no_telemetry: u64::from(outcome == Outcome::LostData),
            first_no_telemetry: (outcome == Outcome::LostData).then_some(5),
            replies_lost: 0,
            first_reply_lost: None,
            duplicate_replies: 0,
            refused_replies: 0,
            refused_replies_why: None,
            stamps_replaced: 0,
            outcome,
            fault,
        };
        LawMetrics {
            status: end.status(),
            reason: end.reason(),
            status_tick: end.status_tick(),
            fault_kind: end.fault.as_ref().map(|f| f.kind),
            completed: end.outcome == Outcome::Completed,
            diverged_at_tick: match end.outcome {
                Outcome::Diverged { tick, .. } => Some(tick),
                _ => None,
            },
            ..m.clone()
        }
    }

    #[test]
    fn regression_sweep_row_status_and_reason() {
        let job = s2_tdc_realtime_job();
        let ok = some_metrics();
        assert!(ok.completed);
        let rt = LoopMode::Realtime;
        let empty_timing = deltaloop_timing::Timing::default().summary();
        assert_eq!(empty_timing.round_trip.count, 0);

        let r = row(&job, 3e-4, rt, Some(&ok), None, Some(&empty_timing));
        assert_eq!((r.status, r.reason.as_str()), (RunStatus::Ok, ""));
        // No round-trip sample: no percentile, not 0.
        assert_eq!(r.round_trip_p999_us, None);
        let mut w = csv::Writer::from_writer(Vec::new());
        w.serialize(&r).unwrap();
        let text = String::from_utf8(w.into_inner().unwrap()).unwrap();
        let mut rd = csv::Reader::from_reader(text.as_bytes());
        let col = rd
            .headers()
            .unwrap()
            .iter()
            .position(|h| h == "round_trip_p999_us");
        let rec = rd.records().next().unwrap().unwrap();
        assert_eq!(&rec[col.unwrap()], "", "{text}");

        // A controller too slow for its deadlines: the plant stops on a fault. Not a divergence,
        // even if the error passed the bound while the torque was held.
        let slow = Fault {
            tick: 99,
            kind: FaultKind::ControllerSilent,
            cause: "no torque within the budget for 100 consecutive ticks".into(),
        };
        let m = ended(&ok, Outcome::Faulted, Some(slow.clone()));
        let r = row(&job, 3e-4, rt, Some(&m), None, Some(&empty_timing));
        assert_eq!(r.status, RunStatus::Fault);
        assert_eq!(m.fault_kind, Some(FaultKind::ControllerSilent));
        assert_eq!(r.reason, m.reason.clone().unwrap());
        let drifted = Outcome::Diverged {
            tick: 120,
            reason: "|e| > 0.5 rad".into(),
        };
        let m = ended(&ok, drifted, Some(slow.clone()));
        let r = row(&job, 3e-4, rt, Some(&m), None, None);
        assert_eq!((r.status, r.diverged_at_tick), (RunStatus::Fault, None));
        // A stop on request nobody here made is its own status.
        let stop = Fault {
            kind: FaultKind::Stopped,
            ..slow
        };
        let r = row(
            &job,
            3e-4,
            rt,
            Some(&ended(&ok, Outcome::Faulted, Some(stop))),
            None,
            None,
        );
        assert_eq!(r.status, RunStatus::Stopped);

        // Interrupted: marked, no metrics, not a result.
        let m = ended(&ok, Outcome::Interrupted { tick: 42 }, None);
        let r = row(&job, 3e-4, rt, Some(&m), None, Some(&empty_timing));
        assert_eq!(r.status, RunStatus::Interrupted);
        assert!(!r.is_result() && r.rms_rad.is_nan() && r.deadline_misses.is_none());

        // Diverged: the tick, and a reason even without a recorded one.
        let at7 = Outcome::Diverged {
            tick: 7,
            reason: String::new(),
        };
        let r = row(&job, 3e-4, rt, Some(&ended(&ok, at7, None)), None, None);
        assert_eq!(
            (r.status, r.diverged_at_tick),
            (RunStatus::Diverged, Some(7))
        );
        assert!(!r.reason.is_empty());
        let r = row(&job, 3e-4, rt, None, Some("boom".into()), None);
        assert_eq!((r.status, r.reason.as_str()), (RunStatus::Error, "boom"));
        let r = row(&job, 3e-4, rt, Some(&ok), Some("boom".into()), None);
        assert_eq!(r.status, RunStatus::Error);
        // The loop finished but the supervisor lost ticks: its own status, with the reason; the
        // csv says `lost_data`, and a row of an older sweep (`lost-data`) still reads.
        let m = ended(&ok, Outcome::LostData, None);
        let r = row(&job, 3e-4, rt, Some(&m), None, None);
        assert_eq!(r.status, RunStatus::LostData);
        assert!(!r.reason.is_empty());
        let mut w = csv::Writer::from_writer(Vec::new());
        w.serialize(&r).unwrap();
        let text = String::from_utf8(w.into_inner().unwrap()).unwrap();
        assert!(text.contains(",lost_data,"), "{text}");
        let old = text.replace(",lost_data,", ",lost-data,");
        let back: Row = csv::Reader::from_reader(old.as_bytes())
            .deserialize()
            .next()
            .unwrap()
            .unwrap();
        assert_eq!(back.status, RunStatus::LostData);

        // The report counts them apart and leaves the interrupted point out.
        let sw: SweepFile = toml::from_str(
            "name = \"r\"\nbase = \"b.toml\"\nscenarios = [\"s2\"]\npresets = [\"matched\"]\nlaws = [\"tdc\"]\ntde_delay_samples = [1]\ntransport_delay_samples = [0]\ncompute_delay_us = [200, 300]\n"
        )
        .unwrap();
        let too_slow = Fault {
            tick: 99,
            kind: FaultKind::ControllerSilent,
            cause: "too slow".into(),
        };
        let m = ended(&ok, Outcome::Faulted, Some(too_slow));
        let stopped = row(&job, 3e-4, rt, Some(&m), None, Some(&empty_timing));
        let m = ended(&ok, Outcome::Interrupted { tick: 3 }, None);
        let cut = row(
            &Job {
                kind: PointKind::Compute { us: 300 },
                ..job.clone()
            },
            3e-4,
            rt,
            Some(&m),
            None,
            None,
        );
        let md = report(&sw, &[stopped, cut], &[], Path::new("s.toml"));
        assert!(md.contains(" 1 points;"), "{md}");
        assert!(
            md.contains("Diverged: 0; stopped on a loop fault: 1; errors: 0."),
            "{md}"
        );
        assert!(
            md.contains("| fault |") && md.contains("fault at tick 99: too slow"),
            "{md}"
        );
        assert!(!md.contains("interrupted"), "{md}");
    }
}
