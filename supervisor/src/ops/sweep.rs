//! `deltaloop sweep <sweep.toml>`: a grid of runs (scenarios × presets × laws × ℓ × d, plus a
//! realtime compute-delay axis), each through the same code as `deltaloop run`. Writes
//! `sweep.csv` (row by row, so an interrupted sweep keeps what finished), `sweep.json`,
//! `report.md` and plots of RMS error, TDE error and δ_N against each delay.
//!
//! A sweep is a [`plan::Plan`] (every point with a stable id); [`shard`] runs any subset of it
//! into a folder of its own, and [`merge`] turns shard folders into the sweep's outputs. The
//! one-machine sweep is the same path: plan, run every point into the output folder, merge it.

use crate::loops::inproc;
use crate::loops::lawrun::Keep;
use crate::loops::procs;
use crate::output::plot::{self, Panel, Series};
use crate::record::metrics::LawMetrics;
use crate::study::Study;
use anyhow::{Context, Result, bail};
use deltaloop_config::config::{self as cfgfile, PathKind};
use deltaloop_config::{ConfigError, Law, LoopMode, Preset, RunConfig};
use serde::{Deserialize, Serialize};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

pub mod cmd;
pub mod merge;
pub mod plan;
pub mod shard;

/// The sweep file.
#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct SweepFile {
    pub name: String,
    #[serde(default)]
    pub description: String,
    /// Scenario config every point starts from (plant, loop, sensor), relative to the sweep file.
    /// Its path and preset are replaced by the axes below.
    pub base: PathBuf,
    /// Mode of the deterministic axes: `inproc` or `lockstep`.
    #[serde(default)]
    pub mode: LoopMode,
    pub scenarios: Vec<PathKind>,
    pub presets: Vec<Preset>,
    pub laws: Vec<Law>,
    pub tde_delay_samples: Vec<u32>,
    pub transport_delay_samples: Vec<u32>,
    /// Sub-tick transport delay axis, µs: each value runs every law × scenario × preset at the
    /// first ℓ and d above, with `plant.transport_delay_us` set. Empty: none.
    #[serde(default)]
    pub transport_delay_us: Vec<f64>,
    /// Realtime axis: each value runs every law × scenario × preset in realtime mode at the first
    /// ℓ and d above. Empty: no realtime runs.
    #[serde(default)]
    pub compute_delay_us: Vec<u32>,
}

/// One grid point's result: a row of `sweep.csv`.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Row {
    /// The point's id in the plan (see [`plan::Plan`]).
    pub point: String,
    pub scenario: String,
    pub preset: String,
    pub law: Law,
    pub mode: LoopMode,
    pub tde_delay_samples: u32,
    pub transport_delay_samples: u32,
    /// The sub-tick transport delay, µs (the delay D is d·Ts plus this).
    pub transport_delay_us: f64,
    /// The effective estimation delay L_eff/Ts = ℓ + D/Ts, ticks.
    pub effective_delay_ticks: f64,
    pub compute_delay_us: u32,
    /// How the point ended (see [`Status`]).
    pub status: Status,
    /// Set only for `diverged`.
    pub diverged_at_tick: Option<u64>,
    /// Why, for every status but `ok`.
    pub reason: String,
    /// Max over joints of the RMS joint error, rad.
    pub rms_rad: f64,
    pub max_abs_err_rad: f64,
    pub task_rms_mm: f64,
    /// Max over joints of the TDE error RMS, rad/s².
    pub tde_err_rms: f64,
    /// Max over joints of δ_N max and of its 99.9th percentile, rad/s³.
    pub delta_n_max: f64,
    pub delta_n_p999: f64,
    pub k2_required: f64,
    pub eq43_holds: bool,
    pub hf_torque_share: f64,
    pub clamp_count: u64,
    pub deadline_misses: Option<u64>,
    /// Empty when the run has no round-trip sample (never 0 for "no data").
    pub round_trip_p999_us: Option<f64>,
}

/// How a sweep point ended (`sweep.csv` column `status`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Status {
    /// Every tick ran and was recorded.
    Ok,
    /// The divergence rule ended the run (the physics).
    Diverged,
    /// A loop fault ended it, e.g. a controller too slow for its deadlines.
    Stopped,
    /// The loop finished, but the supervisor lost part of the stream.
    LostData,
    /// Ctrl-C / SIGTERM cut the point short: not a result, no metrics.
    Interrupted,
    /// The point could not run.
    Error,
}

impl Status {
    /// The `sweep.csv` word.
    pub fn name(self) -> &'static str {
        match self {
            Status::Ok => "ok",
            Status::Diverged => "diverged",
            Status::Stopped => "stopped",
            Status::LostData => "lost-data",
            Status::Interrupted => "interrupted",
            Status::Error => "error",
        }
    }
}

impl std::fmt::Display for Status {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.pad(self.name())
    }
}

impl Row {
    /// Whether the row is a result (every status but `interrupted`: a point cut short by
    /// Ctrl-C / SIGTERM measured nothing complete).
    pub fn is_result(&self) -> bool {
        self.status != Status::Interrupted
    }
}

/// One point's parameters.
#[derive(Debug, Clone, PartialEq)]
pub struct Job {
    scenario: PathKind,
    preset: Preset,
    law: Law,
    ell: u32,
    d: u32,
    /// Sub-tick transport delay, µs.
    us: f64,
    compute_us: u32,
    realtime: bool,
}

impl std::fmt::Display for Job {
    /// `s1/matched/tdc ℓ=1 d=0`, and `c=200us (realtime)` for the compute-delay axis.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{}/{}/{} ℓ={} d={}",
            self.scenario.name(),
            self.preset.name(),
            self.law,
            self.ell,
            self.d
        )?;
        if self.us > 0.0 {
            write!(f, " D+={}us", self.us)?;
        }
        if self.realtime {
            write!(f, " c={}us (realtime)", self.compute_us)?;
        }
        Ok(())
    }
}

/// A metric read off a row.
type Metric = fn(&Row) -> f64;

fn maxj(v: [f64; 3]) -> f64 {
    v.into_iter().fold(0.0, f64::max)
}

/// Status and reason of a point (see [`Row::status`]). An interrupt comes first (the point did
/// not finish, whatever else happened), then a loop fault (a stop on a fault is not a
/// divergence, even when the robot drifted past the bound while the plant held the torque of
/// a silent controller), then the divergence rule.
fn status(m: Option<&LawMetrics>, err: Option<&str>) -> (Status, String) {
    let Some(m) = m else {
        let e = err.filter(|e| !e.is_empty()).unwrap_or("no result");
        return (Status::Error, e.to_string());
    };
    if let Some(e) = err {
        return (Status::Error, e.to_string());
    }
    let nonempty = |s: &Option<String>| s.clone().filter(|s| !s.trim().is_empty());
    if let Some(k) = m.interrupted_at_tick {
        return (Status::Interrupted, format!("interrupted at tick {k}"));
    }
    if let Some(f) = nonempty(&m.fault).or_else(|| m.fault_at_tick.map(|_| "loop fault".into())) {
        // The fault text usually names its tick already; otherwise say it.
        let at = match m.fault_at_tick {
            Some(k) if !f.contains(&format!("tick {k}")) => format!("fault at tick {k}: "),
            _ => String::new(),
        };
        let drift = m.diverged_at_tick.map_or(String::new(), |k| {
            format!(
                " (the tracking error had passed the divergence bound at tick {k}: {})",
                nonempty(&m.diverged_reason).unwrap_or_else(|| "diverged".into())
            )
        });
        return (Status::Stopped, format!("{at}{f}{drift}"));
    }
    if let Some(k) = m.diverged_at_tick {
        let why = nonempty(&m.diverged_reason)
            .unwrap_or_else(|| format!("diverged at tick {k} (no reason recorded)"));
        return (Status::Diverged, why);
    }
    if let Some(lost) = nonempty(&m.lost_data) {
        // The loop finished, but the supervisor did not see all of it: not a clean result.
        return (Status::LostData, lost);
    }
    if !m.completed {
        return (
            Status::Stopped,
            format!(
                "the run ended after tick {} without a recorded cause",
                m.ticks
            ),
        );
    }
    (Status::Ok, String::new())
}

fn row(
    job: &Job,
    ts_s: f64,
    mode: LoopMode,
    m: Option<&LawMetrics>,
    err: Option<String>,
    timing: Option<&crate::timing::TimingSummary>,
) -> Row {
    let (status, reason) = status(m, err.as_deref());
    // A point that did not finish carries no metrics: nothing in it is a result.
    let (m, timing) = if status == Status::Interrupted {
        (None, None)
    } else {
        (m, timing)
    };
    let nan = f64::NAN;
    Row {
        point: String::new(),
        scenario: job.scenario.name().into(),
        preset: job.preset.name().into(),
        law: job.law,
        mode,
        tde_delay_samples: job.ell,
        transport_delay_samples: job.d,
        transport_delay_us: job.us,
        effective_delay_ticks: f64::from(job.ell) + f64::from(job.d) + job.us * 1e-6 / ts_s,
        compute_delay_us: job.compute_us,
        status,
        diverged_at_tick: m
            .and_then(|m| m.diverged_at_tick)
            .filter(|_| status == Status::Diverged),
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
    }
}

/// The config of one grid point: the base with the axes applied, validated.
fn point_config(base: &RunConfig, job: &Job) -> Result<RunConfig> {
    let mut c = base.clone();
    c.name = format!(
        "{}-{}-{}-l{}-d{}-u{}-c{}",
        job.scenario.name(),
        job.preset.name(),
        job.law,
        job.ell,
        job.d,
        (job.us * 1e3).round(),
        job.compute_us
    )
    .to_lowercase();
    c.scenario.path = job.scenario;
    c.scenario.segments.clear();
    // The preset axis sets the constants that differ between presets (M̄, φ); the base's other
    // constants (gains) stay as the base resolved them.
    c.controller.preset = job.preset;
    let p = deltaloop_config::ControllerParams::preset(job.preset);
    c.controller.m_bar = Some(p.m_bar);
    c.controller.phi = Some(p.phi);
    c.controller.laws = vec![job.law];
    c.controller.tde_delay_samples = job.ell;
    c.controller.compute_delay_us = job.compute_us;
    c.plant.transport_delay_samples = job.d;
    c.plant.transport_delay_us = job.us;
    c.validate()?;
    Ok(c)
}

fn run_job(base: &RunConfig, job: &Job, mode: LoopMode, dir: &Path) -> Row {
    let ts_s = base.loop_.ts_s;
    let attempt = || -> Result<(LawMetrics, Option<crate::timing::TimingSummary>)> {
        let cfg = point_config(base, job)?;
        let study = Study::new(cfg).context("reference")?;
        let mode = if job.realtime {
            LoopMode::Realtime
        } else {
            mode
        };
        let (run, timing) = if mode.is_process() {
            let pdir = dir.join("points").join(&study.config.name);
            std::fs::create_dir_all(&pdir)?;
            std::fs::write(pdir.join("config.toml"), study.config.to_toml_string())?;
            let r = procs::run_law(&study, job.law, mode, &pdir, &Keep::default())?;
            (r.run, Some(r.timing.summary()))
        } else {
            (inproc::run_law(&study, job.law, &Keep::default())?, None)
        };
        Ok((run.metrics, timing))
    };
    let mode = if job.realtime {
        LoopMode::Realtime
    } else {
        mode
    };
    match std::panic::catch_unwind(std::panic::AssertUnwindSafe(attempt)) {
        Ok(Ok((m, t))) => row(job, ts_s, mode, Some(&m), None, t.as_ref()),
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

/// The first value listed twice on a sweep axis, if any (linear: an axis may list thousands).
fn repeated(values: &[String]) -> Option<&String> {
    let mut seen = std::collections::HashSet::with_capacity(values.len());
    values.iter().find(|v| !seen.insert(v.as_str()))
}

/// Most points a sweep may have. The plan, a merge's rows and `sweep plan --json` (what a
/// cluster driver reads) hold every point in memory, a few hundred bytes each: 10⁵ points are
/// tens of MB, and ≈ 40 CPU-minutes of the cheapest (in-process, ≈ 24 ms each) or days of
/// realtime ones. That covers the largest study docs/guide/cluster.md plans (a 10⁵-point Monte Carlo on a
/// cluster); a grid beyond it is a typo in an axis, or several sweeps. Checked before anything
/// is expanded (regression: a 118 KB file of about 10⁸ points aborted `sweep plan` and
/// `sweep merge` on allocation).
pub const MAX_POINTS: u64 = 100_000;

/// How many points a sweep expands to: scenarios × presets × laws × (ℓ × d + the sub-tick
/// delays above 0 + the compute delays), in checked arithmetic; the error names the axes, their
/// product and [`MAX_POINTS`].
fn point_count(sw: &SweepFile) -> Result<u64> {
    let n = |v: usize| v as u64;
    let us = sw.transport_delay_us.iter().filter(|&&us| us > 0.0).count();
    let count = n(sw.tde_delay_samples.len())
        .checked_mul(n(sw.transport_delay_samples.len()))
        .and_then(|g| g.checked_add(n(us)))
        .and_then(|g| g.checked_add(n(sw.compute_delay_us.len())))
        .and_then(|g| g.checked_mul(n(sw.laws.len())))
        .and_then(|g| g.checked_mul(n(sw.presets.len())))
        .and_then(|g| g.checked_mul(n(sw.scenarios.len())));
    match count {
        Some(c) if c <= MAX_POINTS => Ok(c),
        _ => bail!(
            "the sweep has {} points: scenarios {} × presets {} × laws {} × (tde_delay_samples {} × transport_delay_samples {} + transport_delay_us {us} + compute_delay_us {}), more than the {MAX_POINTS} a sweep may have: split it into several sweep files",
            count.map_or_else(|| "more than 2^64".to_string(), |c| c.to_string()),
            sw.scenarios.len(),
            sw.presets.len(),
            sw.laws.len(),
            sw.tde_delay_samples.len(),
            sw.transport_delay_samples.len(),
            sw.compute_delay_us.len()
        ),
    }
}

/// Checks the sweep file's own keys: name, mode, and every axis non-empty and without repeats
/// (a repeated value would run the same point twice, and `run` rejects a repeated law too).
fn check(sw: &SweepFile) -> Result<()> {
    if !cfgfile::name_is_valid(&sw.name) {
        bail!(
            "sweep key `name` = {} is out of range: {}",
            cfgfile::show_str(&sw.name),
            cfgfile::NAME_RULE
        );
    }
    if sw.mode == LoopMode::Realtime {
        bail!(
            "sweep key `mode` = \"{}\" is out of range: inproc or lockstep (the compute_delay_us axis runs in realtime by itself)",
            sw.mode
        );
    }
    if let Some(&us) = sw
        .transport_delay_us
        .iter()
        .find(|us| !(us.is_finite() && (0.0..=cfgfile::MAX_TRANSPORT_DELAY_US).contains(*us)))
    {
        bail!(
            "sweep key `transport_delay_us` lists {}: each value 0 <= us <= {} µs",
            cfgfile::show_num(us),
            cfgfile::MAX_TRANSPORT_DELAY_US
        );
    }
    point_count(sw)?;
    let axes: [(&str, Vec<String>, bool); 7] = [
        (
            "scenarios",
            sw.scenarios.iter().map(|s| s.name().to_string()).collect(),
            true,
        ),
        (
            "presets",
            sw.presets.iter().map(|p| p.name().to_string()).collect(),
            true,
        ),
        (
            "laws",
            sw.laws.iter().map(|l| l.name().to_string()).collect(),
            true,
        ),
        (
            "tde_delay_samples",
            sw.tde_delay_samples.iter().map(u32::to_string).collect(),
            true,
        ),
        (
            "transport_delay_samples",
            sw.transport_delay_samples
                .iter()
                .map(u32::to_string)
                .collect(),
            true,
        ),
        (
            "transport_delay_us",
            sw.transport_delay_us.iter().map(f64::to_string).collect(),
            false,
        ),
        (
            "compute_delay_us",
            sw.compute_delay_us.iter().map(u32::to_string).collect(),
            false,
        ),
    ];
    for (k, values, required) in axes {
        if required && values.is_empty() {
            bail!("sweep key `{k}` = [] is out of range: at least one value");
        }
        if let Some(v) = repeated(&values) {
            bail!("sweep key `{k}` lists {v} twice: each value at most once");
        }
    }
    Ok(())
}

/// Reads the sweep's base scenario. Its text is never echoed: `base` may name any file (say
/// `/etc/passwd`), so a parse error says only where it is.
fn load_base(path: &Path) -> Result<RunConfig> {
    RunConfig::from_file(path).map_err(|e| match e {
        ConfigError::Parse { position, .. } => anyhow::anyhow!(
            "sweep key `base`: {} is not a valid scenario config (parse error{}; `deltaloop run` on it shows the message)",
            cfgfile::show_path(path),
            position
                .map(|(l, c)| format!(" at line {l}, column {c}"))
                .unwrap_or_default()
        ),
        e => anyhow::anyhow!("sweep key `base`: {e}"),
    })
}

/// Loads and checks a sweep file; returns it with the base config resolved. Like a scenario
/// file, the sweep file and its base are read only if they are regular files of at most
/// [`cfgfile::MAX_FILE_BYTES`].
pub fn load(path: &Path) -> Result<(SweepFile, RunConfig)> {
    load_with_base(path, None)
}

/// [`load`], with the base read from `base` instead of the file's `base` key when given (a copy
/// shipped next to the sweep file; the key stays as written).
pub fn load_with_base(path: &Path, base: Option<&Path>) -> Result<(SweepFile, RunConfig)> {
    let shown = cfgfile::show_path(path);
    let text = cfgfile::read_text_file(path)
        .map_err(|reason| anyhow::anyhow!("cannot read sweep file {shown}: {reason}"))?;
    let sw: SweepFile = toml::from_str(&text).map_err(|e| {
        anyhow::anyhow!(
            "invalid sweep file {shown}: {}",
            cfgfile::toml_error_line(&text, &e)
        )
    })?;
    check(&sw)?;
    let base_path = base.map_or_else(
        || path.parent().unwrap_or(Path::new(".")).join(&sw.base),
        Path::to_path_buf,
    );
    let base = load_base(&base_path)?;
    Ok((sw, base))
}

fn jobs(sw: &SweepFile) -> Vec<Job> {
    let mut v = Vec::new();
    for &scenario in &sw.scenarios {
        for &preset in &sw.presets {
            for &law in &sw.laws {
                for &ell in &sw.tde_delay_samples {
                    for &d in &sw.transport_delay_samples {
                        v.push(Job {
                            scenario,
                            preset,
                            law,
                            ell,
                            d,
                            us: 0.0,
                            compute_us: 0,
                            realtime: false,
                        });
                    }
                }
                // The side axes run at the first ℓ and d; D = 0 is the grid point itself.
                let side = |us, compute_us, realtime| Job {
                    scenario,
                    preset,
                    law,
                    ell: sw.tde_delay_samples[0],
                    d: sw.transport_delay_samples[0],
                    us,
                    compute_us,
                    realtime,
                };
                for &us in sw.transport_delay_us.iter().filter(|&&us| us > 0.0) {
                    v.push(side(us, 0, false));
                }
                for &c in &sw.compute_delay_us {
                    v.push(side(0.0, c, true));
                }
            }
        }
    }
    v
}

/// Loads the sweep file at `path` and runs it into `out`; returns the rows (in grid order).
/// A caller that has already loaded the file (e.g. to name the output folder) passes the result
/// to [`run_loaded`] instead, so the file is read and parsed once.
pub fn run(path: &Path, out: &Path, progress: bool) -> Result<Vec<Row>> {
    let (sw, base) = load(path)?;
    run_loaded(&sw, &base, path, out, progress)
}

/// Runs a sweep loaded by [`load`] from `path` (named in the report) into `out`; returns the
/// rows (in plan order). The same path as a cluster sweep: the plan, every point run into `out`
/// as one shard (`sweep.csv` grows row by row), then `out` merged into itself.
pub fn run_loaded(
    sw: &SweepFile,
    base: &RunConfig,
    path: &Path,
    out: &Path,
    progress: bool,
) -> Result<Vec<Row>> {
    // Every point must be a valid config before anything runs.
    let plan = plan::Plan::new(sw.clone(), base.clone())?;
    let all: Vec<usize> = (0..plan.points.len()).collect();
    plan.check_points(&all)?;
    let jobs = std::thread::available_parallelism().map_or(1, |n| n.get());
    let sweep_file = path.display().to_string();
    shard::run(&plan, &all, &sweep_file, out, jobs, progress)?;
    let interrupted = crate::loops::signals::interrupted();
    let merged = merge::merge(
        &[out.to_path_buf()],
        out,
        merge::Options {
            allow_missing: interrupted,
            interrupted,
        },
    )?;
    if interrupted {
        return Err(anyhow::Error::new(crate::ops::run::Interrupted(
            out.to_path_buf(),
        )));
    }
    Ok(merged.rows)
}

/// A point of the ℓ × d grid (not of the realtime or the sub-tick delay axis).
fn on_grid(r: &Row) -> bool {
    r.mode != LoopMode::Realtime && r.transport_delay_us == 0.0
}

/// (file stem, x axis, metric) of every figure written.
fn plots(sw: &SweepFile, rows: &[Row], out: &Path) -> Result<Vec<(String, String)>> {
    let mut written = Vec::new();
    let metrics: [(&str, &str, Metric); 3] = [
        ("rms", "RMS joint error, max over joints (rad)", |r| {
            r.rms_rad
        }),
        ("tde_err", "TDE error RMS, max over joints (rad/s²)", |r| {
            r.tde_err_rms
        }),
        ("delta_n", "δ_N max, max over joints (rad/s³)", |r| {
            r.delta_n_max
        }),
    ];
    let axes: [(&str, &str, bool); 3] = [
        ("tde_delay", "TDE delay ℓ (ticks)", true),
        ("transport_delay", "transport delay d (ticks)", false),
        ("compute_delay", "controller compute delay (µs)", false),
    ];
    for (axis, x_label, log_x) in axes {
        let x_of = |r: &Row| -> f64 {
            match axis {
                "tde_delay" => f64::from(r.tde_delay_samples),
                "transport_delay" => f64::from(r.transport_delay_samples),
                _ => f64::from(r.compute_delay_us),
            }
        };
        // Hold the other axes at their first value.
        let on_axis = |r: &Row| -> bool {
            let (l0, d0) = (sw.tde_delay_samples[0], sw.transport_delay_samples[0]);
            match axis {
                "tde_delay" => on_grid(r) && r.transport_delay_samples == d0,
                "transport_delay" => on_grid(r) && r.tde_delay_samples == l0,
                _ => r.mode == LoopMode::Realtime,
            }
        };
        let values: Vec<f64> = rows.iter().filter(|r| on_axis(r)).map(x_of).collect();
        let distinct = {
            let mut v = values.clone();
            v.sort_by(f64::total_cmp);
            v.dedup();
            v.len()
        };
        if distinct < 2 {
            continue;
        }
        for (mname, y_label, get) in metrics {
            let mut panels = Vec::new();
            for &sc in &sw.scenarios {
                for &pr in &sw.presets {
                    let scn = sc.name();
                    let series = sw
                        .laws
                        .iter()
                        .map(|law| Series {
                            name: law.name().to_string(),
                            color: plot::law_color(law.name()),
                            points: rows
                                .iter()
                                .filter(|r| {
                                    on_axis(r)
                                        && r.scenario == scn
                                        && r.preset == pr.name()
                                        && r.law == *law
                                        && r.status == Status::Ok
                                })
                                .map(|r| (x_of(r), get(r)))
                                .collect(),
                        })
                        .collect();
                    panels.push(Panel {
                        title: format!("{} — preset {}", scn.to_uppercase(), pr.name()),
                        x_label: x_label.to_string(),
                        y_label: y_label.to_string(),
                        log_x: log_x && values.iter().all(|&v| v > 0.0),
                        log_y: true,
                        series,
                    });
                }
            }
            let stem = format!("{mname}_vs_{axis}");
            plot::figure(
                &out.join(&stem),
                &format!("{} vs {}", y_label, x_label),
                &panels,
                sw.presets.len(),
            )?;
            written.push((stem, format!("{y_label} vs {x_label}")));
        }
    }
    if !sw.transport_delay_us.is_empty() {
        written.extend(effective_delay_figures(sw, rows, out)?);
    }
    Ok(written)
}

/// The delay study's headline: tracking and TDE error against the effective estimation delay
/// L_eff/Ts = ℓ + D/Ts from 1 to 3 ticks, integer ℓ (D = d·Ts at the first d) and the transport
/// delay D (at the first ℓ, whole and sub-tick) as two series per law on the same axes.
fn effective_delay_figures(
    sw: &SweepFile,
    rows: &[Row],
    out: &Path,
) -> Result<Vec<(String, String)>> {
    let (l0, d0) = (sw.tde_delay_samples[0], sw.transport_delay_samples[0]);
    let max_x = f64::from(l0) + f64::from(d0) + 2.0 + 1e-9;
    let metrics: [(&str, &str, Metric); 2] = [
        ("rms", "RMS joint error, max over joints (rad)", |r| {
            r.rms_rad
        }),
        ("tde_err", "TDE error RMS, max over joints (rad/s²)", |r| {
            r.tde_err_rms
        }),
    ];
    let mut written = Vec::new();
    for (mname, y_label, get) in metrics {
        let mut panels = Vec::new();
        for &sc in &sw.scenarios {
            for &pr in &sw.presets {
                let here = |r: &&Row| {
                    r.mode != LoopMode::Realtime
                        && r.scenario == sc.name()
                        && r.preset == pr.name()
                        && r.status == Status::Ok
                        && r.effective_delay_ticks <= max_x
                };
                let mut series = Vec::new();
                for &law in &sw.laws {
                    let points = |by_ell: bool| -> Vec<(f64, f64)> {
                        let mut p: Vec<(f64, f64)> = rows
                            .iter()
                            .filter(here)
                            .filter(|r| r.law == law)
                            .filter(|r| {
                                if by_ell {
                                    on_grid(r) && r.transport_delay_samples == d0
                                } else {
                                    r.tde_delay_samples == l0
                                }
                            })
                            .map(|r| (r.effective_delay_ticks, get(r)))
                            .collect();
                        p.sort_by(|a, b| a.0.total_cmp(&b.0));
                        p
                    };
                    series.push(Series {
                        name: format!("{law}: ℓ"),
                        color: plot::law_color(law.name()),
                        points: points(true),
                    });
                    series.push(Series {
                        name: format!("{law}: D (µs)"),
                        color: plot::lighter(plot::law_color(law.name())),
                        points: points(false),
                    });
                }
                panels.push(Panel {
                    title: format!("{} — preset {}", sc.name().to_uppercase(), pr.name()),
                    x_label: "effective estimation delay L_eff/Ts = ℓ + D/Ts".into(),
                    y_label: y_label.to_string(),
                    log_x: false,
                    log_y: true,
                    series,
                });
            }
        }
        let stem = format!("{mname}_vs_effective_delay");
        let title = format!("{y_label} vs the effective delay ℓ + D/Ts");
        plot::figure(&out.join(&stem), &title, &panels, sw.presets.len())?;
        written.push((stem, title));
    }
    Ok(written)
}

/// The largest sub-tick transport delay (µs) on the grid up to which a law's tracking RMS stays
/// within 2× its value at D = 0 (every delay up to it included), and the RMS there; None without
/// a D = 0 result.
fn latency_budget(
    sw: &SweepFile,
    rows: &[Row],
    scenario: &str,
    preset: &str,
    law: Law,
) -> Option<(f64, f64, f64)> {
    let (l0, d0) = (sw.tde_delay_samples[0], sw.transport_delay_samples[0]);
    let at = |us: f64| {
        rows.iter().find(|r| {
            r.mode != LoopMode::Realtime
                && r.scenario == scenario
                && r.preset == preset
                && r.law == law
                && r.tde_delay_samples == l0
                && r.transport_delay_samples == d0
                && r.transport_delay_us == us
        })
    };
    let zero = at(0.0).filter(|r| r.status == Status::Ok)?.rms_rad;
    let mut grid: Vec<f64> = sw.transport_delay_us.clone();
    grid.retain(|&us| us > 0.0);
    grid.sort_by(f64::total_cmp);
    let mut best = (0.0, zero);
    for us in grid {
        match at(us) {
            Some(r) if r.status == Status::Ok && r.rms_rad <= 2.0 * zero => best = (us, r.rms_rad),
            _ => break,
        }
    }
    Some((zero, best.0, best.1))
}

fn cell(r: Option<&Row>, get: Metric) -> String {
    match r {
        None => "–".into(),
        Some(r) => match r.status {
            Status::Ok => format!("{:.2e}", get(r)),
            Status::Diverged => format!("div@{}", r.diverged_at_tick.unwrap_or(0)),
            Status::Interrupted => "–".into(),
            other => other.name().into(),
        },
    }
}

/// One markdown table: a row per law, a column per value of one delay axis.
fn axis_table<'a>(
    s: &mut String,
    caption: &str,
    sym: &str,
    values: &[u32],
    laws: &[Law],
    find: impl Fn(Law, u32) -> Option<&'a Row>,
    get: Metric,
) {
    let _ = writeln!(s, "{caption}:\n");
    let _ = write!(s, "| law |");
    for v in values {
        let _ = write!(s, " {sym}={v} |");
    }
    let _ = writeln!(s, "\n|---|{}", "---|".repeat(values.len()));
    for &law in laws {
        let _ = write!(s, "| `{law}` |");
        for &v in values {
            let _ = write!(s, " {} |", cell(find(law, v), get));
        }
        let _ = writeln!(s);
    }
    let _ = writeln!(s);
}

fn report(sw: &SweepFile, rows: &[Row], figures: &[(String, String)], path: &Path) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "# Sweep `{}`\n\n{}\n\nProduced by: `deltaloop sweep {}`. {} runs; deterministic axes in `{}` mode.\n",
        sw.name,
        sw.description,
        path.display(),
        rows.iter().filter(|r| r.is_result()).count(),
        sw.mode
    );
    let count = |st: Status| rows.iter().filter(|r| r.status == st).count();
    let (div, stopped, lost, err) = (
        count(Status::Diverged),
        count(Status::Stopped),
        count(Status::LostData),
        count(Status::Error),
    );
    // These counts only when there are some: a normal sweep's report stays as it was.
    let stopped_count = [
        (stopped, "stopped on a loop fault"),
        (lost, "lost data (the supervisor fell behind)"),
    ]
    .iter()
    .filter(|(n, _)| *n > 0)
    .map(|(n, what)| format!("; {what}: {n}"))
    .collect::<String>();
    let _ = writeln!(
        s,
        "Diverged: {div}{stopped_count}; errors: {err}. A run diverges at the first tick with |e| > 0.5 rad, a non-finite value, or the robot leaving its workspace; it is recorded there (`div@tick`), never crashes the sweep.\n"
    );
    if stopped > 0 {
        let _ = writeln!(
            s,
            "A stopped run ended on a loop fault, not by diverging: e.g. a controller that missed its torque budget `faults.controller_silence_ticks` times in a row, after which the plant braked to a safe stop. The fault is the row's `reason` in `sweep.csv`.\n"
        );
    }
    let tables: [(&str, Metric); 2] = [
        ("RMS joint error, max over joints (rad)", |r| r.rms_rad),
        ("TDE error RMS, max over joints (rad/s²)", |r| {
            r.tde_err_rms
        }),
    ];
    for &sc in &sw.scenarios {
        let scn = sc.name();
        for &pr in &sw.presets {
            for (title, get) in tables {
                let _ = writeln!(
                    s,
                    "## {} — preset `{}`: {title}\n",
                    scn.to_uppercase(),
                    pr.name()
                );
                let (l0, d0) = (sw.tde_delay_samples[0], sw.transport_delay_samples[0]);
                let base = |r: &&Row| on_grid(r) && r.scenario == scn && r.preset == pr.name();
                let by_ell = |law: Law, l: u32| {
                    rows.iter().filter(base).find(|r| {
                        r.law == law && r.tde_delay_samples == l && r.transport_delay_samples == d0
                    })
                };
                let by_d = |law: Law, d: u32| {
                    rows.iter().filter(base).find(|r| {
                        r.law == law && r.tde_delay_samples == l0 && r.transport_delay_samples == d
                    })
                };
                axis_table(
                    &mut s,
                    &format!("Against the TDE delay ℓ (transport delay d = {d0})"),
                    "ℓ",
                    &sw.tde_delay_samples,
                    &sw.laws,
                    by_ell,
                    get,
                );
                axis_table(
                    &mut s,
                    &format!("Against the transport delay d (ℓ = {l0})"),
                    "d",
                    &sw.transport_delay_samples,
                    &sw.laws,
                    by_d,
                    get,
                );
                let _ = writeln!(s);
            }
        }
    }
    if !sw.compute_delay_us.is_empty() {
        let _ = writeln!(
            s,
            "## Controller compute delay (realtime)\n\n| scenario | preset | law | compute delay (µs) | status | RMS (rad) | misses | round trip p99.9 (µs) | reason |\n|---|---|---|---|---|---|---|---|---|"
        );
        for r in rows
            .iter()
            .filter(|r| r.mode == LoopMode::Realtime && r.is_result())
        {
            let _ = writeln!(
                s,
                "| {} | {} | `{}` | {} | {} | {:.2e} | {} | {} | {} |",
                r.scenario,
                r.preset,
                r.law,
                r.compute_delay_us,
                r.status,
                r.rms_rad,
                r.deadline_misses.map_or("–".into(), |m| m.to_string()),
                r.round_trip_p999_us
                    .map_or("–".into(), |p| format!("{p:.1}")),
                r.reason.replace('|', "\\|").replace('\n', " ")
            );
        }
        let _ = writeln!(s);
    }
    if !sw.transport_delay_us.is_empty() {
        let _ = writeln!(
            s,
            "## Latency budget\n\nThe largest transport delay D on the grid (at ℓ = {}, d = {}) up to which each law's tracking RMS stays within 2× its value at D = 0. Delays are sub-tick: a command takes effect at t_k + D, cutting the interval (docs/delta-robot.md §5.2).\n\n| scenario | preset | law | RMS at D = 0 (rad) | latency budget (µs) | RMS there (rad) |\n|---|---|---|---|---|---|",
            sw.tde_delay_samples[0], sw.transport_delay_samples[0]
        );
        for &sc in &sw.scenarios {
            for &pr in &sw.presets {
                for &law in &sw.laws {
                    if let Some((zero, us, rms)) =
                        latency_budget(sw, rows, sc.name(), pr.name(), law)
                    {
                        let _ = writeln!(
                            s,
                            "| {} | {} | `{law}` | {zero:.3e} | {us} | {rms:.3e} |",
                            sc.name(),
                            pr.name()
                        );
                    }
                }
            }
        }
        let _ = writeln!(s);
    }
    let _ = writeln!(s, "## Figures\n");
    for (stem, title) in figures {
        let _ = writeln!(s, "### {title}\n\n![{title}]({stem}.png)\n");
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A scratch folder with a valid base, removed on drop.
    struct Scratch(PathBuf);
    impl Drop for Scratch {
        fn drop(&mut self) {
            let _ = std::fs::remove_dir_all(&self.0);
        }
    }
    fn scratch(tag: &str) -> Scratch {
        let dir =
            std::env::temp_dir().join(format!("deltaloop-sweep-{tag}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::write(dir.join("base.toml"), "[scenario]\npath = \"s1\"\n").unwrap();
        Scratch(dir)
    }

    const AXES: &str = "scenarios = [\"s1\"]\npresets = [\"matched\"]\nlaws = [\"tdc\"]\ntde_delay_samples = [1]\ntransport_delay_samples = [0]\n";

    /// `load`'s error for a sweep file with `text` (the axes are appended when `axes`).
    fn load_err(dir: &Path, text: &str) -> String {
        let path = dir.join("sweep.toml");
        std::fs::write(&path, text).unwrap();
        let e = format!("{:#}", load(&path).unwrap_err());
        assert!(!e.contains(['\n', '\r']), "one line: {e}");
        e
    }

    /// Regression: no cap on a sweep's size (10⁸ points aborted on allocation). The count is
    /// the product of the axes, checked before expanding: the cap itself passes, one more
    /// point does not, and the line names every axis.
    #[test]
    fn regression_sweep_points_are_counted_and_capped_before_expanding() {
        let d = scratch("cap");
        let list = |n: usize| {
            let v: Vec<String> = (0..n).map(|i| i.to_string()).collect();
            format!("[{}]", v.join(","))
        };
        let file = |ells: usize, ds: usize, compute: usize| {
            format!(
                "name = \"c\"\nbase = \"base.toml\"\nscenarios = [\"s1\", \"s2\"]\npresets = [\"matched\"]\nlaws = [\"tdc\"]\ntde_delay_samples = {}\ntransport_delay_samples = {}\ncompute_delay_us = {}\n",
                list(ells),
                list(ds),
                list(compute)
            )
        };
        let sw: SweepFile = toml::from_str(&file(250, 200, 0)).unwrap();
        assert_eq!(point_count(&sw).unwrap(), MAX_POINTS);
        let e = load_err(&d.0, &file(250, 200, 1));
        assert_eq!(
            e,
            "the sweep has 100002 points: scenarios 2 × presets 1 × laws 1 × (tde_delay_samples 250 × transport_delay_samples 200 + transport_delay_us 0 + compute_delay_us 1), more than the 100000 a sweep may have: split it into several sweep files"
        );
    }

    #[test]
    fn regression_sweep_name_escapes_the_run_folder() {
        let d = scratch("name");
        for bad in [
            "../../../../tmp/victim",
            "a/b",
            "x\ny",
            "\u{200f}x",
            ".x",
            "-x",
            "",
        ] {
            let e = load_err(
                &d.0,
                &format!(
                    "name = {}\nbase = \"base.toml\"\n{AXES}",
                    toml::Value::from(bad)
                ),
            );
            assert_eq!(
                e,
                format!(
                    "sweep key `name` = {} is out of range: {}",
                    cfgfile::show_str(bad),
                    cfgfile::NAME_RULE
                )
            );
        }
    }

    #[test]
    fn regression_sweep_rejects_duplicate_axis_values() {
        let d = scratch("dup");
        let head = "name = \"dup\"\nbase = \"base.toml\"\n";
        for (key, list, shown) in [
            ("laws", "[\"tdc\", \"pid\", \"tdc\"]", "tdc"),
            ("scenarios", "[\"s1\", \"s1\"]", "s1"),
            ("presets", "[\"paper\", \"paper\"]", "paper"),
            ("tde_delay_samples", "[1, 2, 2]", "2"),
            ("transport_delay_samples", "[0, 0]", "0"),
            ("compute_delay_us", "[50, 50]", "50"),
        ] {
            let axes: String = AXES
                .lines()
                .filter(|l| !l.starts_with(&format!("{key} ")))
                .map(|l| format!("{l}\n"))
                .collect();
            let e = load_err(&d.0, &format!("{head}{axes}{key} = {list}\n"));
            assert_eq!(
                e,
                format!("sweep key `{key}` lists {shown} twice: each value at most once")
            );
        }
    }

    #[test]
    fn regression_sweep_base_content_is_never_echoed() {
        let d = scratch("base");
        std::fs::write(d.0.join("secret.toml"), "password = \"hunter2\"\n").unwrap();
        std::fs::write(d.0.join("syntax.toml"), "[scenario]\nhunter2 hunter2\n").unwrap();
        for (base, at) in [
            ("/etc/passwd", Some("line 1, column")),
            ("secret.toml", Some("line 1, column 1")),
            ("syntax.toml", Some("line 2, column 9")),
        ] {
            if !Path::new(base).is_absolute() || Path::new(base).is_file() {
                let e = load_err(&d.0, &format!("name = \"b\"\nbase = {base:?}\n{AXES}"));
                assert!(
                    e.starts_with("sweep key `base`: ")
                        && e.contains("is not a valid scenario config (parse error at ")
                        && at.is_none_or(|a| e.contains(a))
                        && !e.contains("root:")
                        && !e.contains("hunter2")
                        && !e.contains("password"),
                    "{e}"
                );
            }
        }
        // A valid TOML base that fails validation names the key and the value, as `run` would.
        std::fs::write(
            d.0.join("range.toml"),
            "[scenario]\npath = \"s1\"\nhold_s = -1.0\n",
        )
        .unwrap();
        let e = load_err(
            &d.0,
            &format!("name = \"b\"\nbase = \"range.toml\"\n{AXES}"),
        );
        assert!(
            e.starts_with("sweep key `base`: config key `scenario.hold_s` = -1"),
            "{e}"
        );
    }

    #[test]
    fn regression_sweep_and_base_files_must_be_small_regular_files() {
        let d = scratch("read");
        // The sweep file itself.
        for (path, kind) in [
            (d.0.clone(), "a directory"),
            (PathBuf::from("/dev/zero"), "a character device"),
        ] {
            let e = format!("{:#}", load(&path).unwrap_err());
            assert_eq!(
                e,
                format!(
                    "cannot read sweep file {}: it is {kind}, not a regular file",
                    path.display()
                )
            );
        }
        let big = d.0.join("big.toml");
        std::fs::write(&big, "#".repeat(cfgfile::MAX_FILE_BYTES as usize + 1)).unwrap();
        let e = format!("{:#}", load(&big).unwrap_err());
        assert!(e.contains("larger than 1 MiB"), "{e}");
        // Its base.
        for base in ["/dev/zero", "."] {
            let e = load_err(&d.0, &format!("name = \"b\"\nbase = {base:?}\n{AXES}"));
            assert!(
                e.starts_with("sweep key `base`: cannot read config file ")
                    && e.ends_with("not a regular file"),
                "{e}"
            );
        }
    }

    #[test]
    fn regression_sweep_parse_error_is_one_line() {
        let d = scratch("parse");
        let e = load_err(
            &d.0,
            &format!("name = \"p\"\nbase = \"base.toml\"\n{AXES}lawz = 1\n"),
        );
        assert!(
            e.contains("invalid sweep file ")
                && e.contains(": unknown field `lawz`, expected one of")
                && e.ends_with(" at line 8, column 1"),
            "{e}"
        );
    }

    #[test]
    fn regression_sweep_point_error_has_no_debug_text() {
        let d = scratch("point");
        let path = d.0.join("sweep.toml");
        std::fs::write(
            &path,
            "name = \"pt\"\nbase = \"base.toml\"\nscenarios = [\"s1\"]\npresets = [\"matched\"]\nlaws = [\"tdc\"]\ntde_delay_samples = [0]\ntransport_delay_samples = [0]\n",
        )
        .unwrap();
        let (sw, base) = load(&path).unwrap();
        let e = format!(
            "{:#}",
            run_loaded(&sw, &base, &path, &d.0.join("out"), false).unwrap_err()
        );
        assert_eq!(
            e,
            "sweep point s1/matched/tdc ℓ=0 d=0: config key `controller.tde_delay_samples` = 0 is out of range: 1 <= tde_delay_samples <= 10000 ticks"
        );
        let rt = Job {
            scenario: PathKind::S2,
            preset: Preset::Paper,
            law: Law::TdeIs,
            ell: 2,
            d: 1,
            us: 0.0,
            compute_us: 200,
            realtime: true,
        };
        assert_eq!(rt.to_string(), "s2/paper/tde-is ℓ=2 d=1 c=200us (realtime)");
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

    #[test]
    fn regression_sweep_row_status_and_reason() {
        let job = Job {
            scenario: PathKind::S2,
            preset: Preset::Matched,
            law: Law::Tdc,
            ell: 1,
            d: 0,
            us: 0.0,
            compute_us: 200,
            realtime: true,
        };
        let ok = some_metrics();
        assert!(ok.completed);
        let rt = LoopMode::Realtime;
        let empty_timing = crate::timing::Timing::default().summary();
        assert_eq!(empty_timing.round_trip.count, 0);

        let r = row(&job, 3e-4, rt, Some(&ok), None, Some(&empty_timing));
        assert_eq!((r.status, r.reason.as_str()), (Status::Ok, ""));
        // No round-trip sample: no percentile, not 0.
        assert_eq!(r.round_trip_p999_us, None);
        let mut w = csv::Writer::from_writer(Vec::new());
        w.serialize(&r).unwrap();
        let text = String::from_utf8(w.into_inner().unwrap()).unwrap();
        assert!(text.trim_end().ends_with(",0,"), "{text}");

        // A controller too slow for its deadlines: the plant stops on a fault. Not a divergence,
        // even if the error passed the bound while the torque was held.
        let mut m = ok.clone();
        m.completed = false;
        m.fault_at_tick = Some(99);
        m.fault = Some("no torque within the budget for 100 consecutive ticks".into());
        let r = row(&job, 3e-4, rt, Some(&m), None, Some(&empty_timing));
        assert_eq!(r.status, Status::Stopped);
        assert_eq!(
            r.reason,
            "fault at tick 99: no torque within the budget for 100 consecutive ticks"
        );
        m.diverged_at_tick = Some(120);
        m.diverged_reason = Some("|e| > 0.5 rad".into());
        let r = row(&job, 3e-4, rt, Some(&m), None, None);
        assert_eq!((r.status, r.diverged_at_tick), (Status::Stopped, None));
        assert!(r.reason.starts_with("fault at tick 99: ") && r.reason.contains("tick 120"));

        // Interrupted: marked, no metrics, not a result.
        let mut m = ok.clone();
        m.completed = false;
        m.interrupted_at_tick = Some(42);
        let r = row(&job, 3e-4, rt, Some(&m), None, Some(&empty_timing));
        assert_eq!(
            (r.status, r.reason.as_str()),
            (Status::Interrupted, "interrupted at tick 42")
        );
        assert!(!r.is_result() && r.rms_rad.is_nan() && r.deadline_misses.is_none());

        // Diverged without a recorded reason still says why.
        let mut m = ok.clone();
        m.completed = false;
        m.diverged_at_tick = Some(7);
        let r = row(&job, 3e-4, rt, Some(&m), None, None);
        assert_eq!(r.status, Status::Diverged);
        assert_eq!(r.diverged_at_tick, Some(7));
        assert!(!r.reason.is_empty());
        // Ended early with no cause at all: not ok, not diverged.
        let mut m = ok.clone();
        m.completed = false;
        let r = row(&job, 3e-4, rt, Some(&m), None, None);
        assert!(r.status == Status::Stopped && !r.reason.is_empty(), "{r:?}");
        let r = row(&job, 3e-4, rt, None, Some("boom".into()), None);
        assert_eq!((r.status, r.reason.as_str()), (Status::Error, "boom"));
        // The loop finished but the supervisor lost ticks: its own status, with the reason; the
        // csv says `lost-data`.
        let mut m = ok.clone();
        m.completed = false;
        m.lost_ticks = 1600;
        m.lost_data = Some("the supervisor lost 1600 ticks of the stream".into());
        let r = row(&job, 3e-4, rt, Some(&m), None, None);
        assert_eq!(
            (r.status, r.reason.as_str()),
            (
                Status::LostData,
                "the supervisor lost 1600 ticks of the stream"
            )
        );
        let mut w = csv::Writer::from_writer(Vec::new());
        w.serialize(&r).unwrap();
        assert!(
            String::from_utf8(w.into_inner().unwrap())
                .unwrap()
                .contains(",lost-data,")
        );

        // The report counts them apart and leaves the interrupted point out.
        let sw: SweepFile = toml::from_str(
            "name = \"r\"\nbase = \"b.toml\"\nscenarios = [\"s2\"]\npresets = [\"matched\"]\nlaws = [\"tdc\"]\ntde_delay_samples = [1]\ntransport_delay_samples = [0]\ncompute_delay_us = [200, 300]\n"
        )
        .unwrap();
        let mut m = ok.clone();
        m.completed = false;
        m.fault_at_tick = Some(99);
        m.fault = Some("too slow".into());
        let stopped = row(&job, 3e-4, rt, Some(&m), None, Some(&empty_timing));
        m.fault = None;
        m.fault_at_tick = None;
        m.interrupted_at_tick = Some(3);
        let cut = row(
            &Job {
                compute_us: 300,
                ..job.clone()
            },
            3e-4,
            rt,
            Some(&m),
            None,
            None,
        );
        let md = report(&sw, &[stopped, cut], &[], Path::new("s.toml"));
        assert!(md.contains(" 1 runs;"), "{md}");
        assert!(
            md.contains("Diverged: 0; stopped on a loop fault: 1; errors: 0."),
            "{md}"
        );
        assert!(
            md.contains("| stopped |") && md.contains("fault at tick 99: too slow"),
            "{md}"
        );
        assert!(!md.contains("interrupted"), "{md}");
    }

    /// The file is read once: what `load` returned is what runs, even if the file is gone.
    #[test]
    fn run_loaded_runs_what_it_is_given_without_rereading_the_file() {
        let dir = std::env::temp_dir().join(format!("deltaloop-sweep-once-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::write(dir.join("base.toml"), "[scenario]\npath = \"s1\"\n").unwrap();
        let path = dir.join("sweep.toml");
        std::fs::write(
            &path,
            "name = \"once\"\nbase = \"base.toml\"\nscenarios = [\"s1\"]\npresets = [\"matched\"]\n\
             laws = [\"tdc\"]\ntde_delay_samples = [1]\ntransport_delay_samples = [0]\n",
        )
        .unwrap();
        let (mut sw, base) = load(&path).unwrap();
        std::fs::remove_file(&path).unwrap();
        sw.laws = vec![Law::Pid];
        let rows = run_loaded(&sw, &base, &path, &dir.join("out"), false);
        let _ = std::fs::remove_dir_all(&dir);
        let rows = rows.unwrap();
        assert_eq!(rows.len(), 1);
        assert_eq!((rows[0].law, rows[0].status), (Law::Pid, Status::Ok));
    }

    /// The sub-tick delay axis: its points sit on L_eff/Ts = ℓ + D/Ts, D = 300 µs is the grid's
    /// d = 1 bit for bit, and the latency budget is the largest D within 2× the zero-delay RMS
    /// (S2, matched, tdc: 7.2e-5 rad at 0, 9.5e-5 at 45 µs, 2.0e-4 at 300 µs).
    #[test]
    fn sub_tick_delay_axis_effective_delay_and_latency_budget() {
        let dir = scratch("us");
        let path = dir.0.join("sweep.toml");
        std::fs::write(
            dir.0.join("base.toml"),
            "[scenario]\npath = \"s2\"\n[plant]\nfriction = true\n",
        )
        .unwrap();
        std::fs::write(
            &path,
            "name = \"us\"\nbase = \"base.toml\"\nscenarios = [\"s2\"]\npresets = [\"matched\"]\n\
             laws = [\"tdc\"]\ntde_delay_samples = [1]\ntransport_delay_samples = [0, 1]\n\
             transport_delay_us = [0, 45, 300]\n",
        )
        .unwrap();
        let rows = run(&path, &dir.0.join("out"), false).unwrap();
        let leff: Vec<(u32, f64, f64)> = rows
            .iter()
            .map(|r| {
                (
                    r.transport_delay_samples,
                    r.transport_delay_us,
                    r.effective_delay_ticks,
                )
            })
            .collect();
        assert_eq!(
            leff,
            [
                (0, 0.0, 1.0),
                (1, 0.0, 2.0),
                (0, 45.0, 1.15),
                (0, 300.0, 2.0)
            ]
        );
        assert_eq!(rows[3].rms_rad, rows[1].rms_rad, "300 µs is d = 1");
        let md = std::fs::read_to_string(dir.0.join("out/report.md")).unwrap();
        assert!(
            md.contains("| s2 | matched | `tdc` | 7.209e-5 | 45 | 9.454e-5 |"),
            "{md}"
        );
        assert!(dir.0.join("out/rms_vs_effective_delay.png").is_file());
    }
}
