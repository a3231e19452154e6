//! One point of a sweep: its config, its run (through the same code as `deltaloop run`), and
//! its row of `sweep.csv` with the status the run ended in.

use super::schema::Job;
use crate::loops::lawrun::Keep;
use crate::loops::{self, Ran};
use crate::record::metrics::LawMetrics;
use crate::study::Study;
use anyhow::{Context, Result};
use deltaloop_config::{Law, LoopMode, RunConfig};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// One grid point's result: a row of `sweep.csv`.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Row {
    /// The point's id in the plan (see [`super::plan::Plan`]).
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

/// A metric read off a row.
pub(super) type Metric = fn(&Row) -> f64;

pub(super) fn maxj(v: [f64; 3]) -> f64 {
    v.into_iter().fold(0.0, f64::max)
}

/// Status and reason of a point (see [`Row::status`]). An interrupt comes first (the point did
/// not finish, whatever else happened), then a loop fault (a stop on a fault is not a
/// divergence, even when the robot drifted past the bound while the plant held the torque of
/// a silent controller), then the divergence rule.
pub(super) fn status(m: Option<&LawMetrics>, err: Option<&str>) -> (Status, String) {
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

pub(super) fn row(
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
pub(super) fn point_config(base: &RunConfig, job: &Job) -> Result<RunConfig> {
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

pub(super) fn run_job(base: &RunConfig, job: &Job, mode: LoopMode, dir: &Path) -> Row {
    let ts_s = base.loop_.ts_s;
    let attempt = || -> Result<(LawMetrics, Option<crate::timing::TimingSummary>)> {
        let cfg = point_config(base, job)?;
        let study = Study::new(cfg).context("reference")?;
        let mode = if job.realtime {
            LoopMode::Realtime
        } else {
            mode
        };
        let pdir = dir.join("points").join(&study.config.name);
        if mode.is_process() {
            std::fs::create_dir_all(&pdir)?;
            std::fs::write(pdir.join("config.toml"), study.config.to_toml_string())?;
        }
        Ok(
            match loops::run_law(&study, job.law, mode, &pdir, &Keep::default(), None)? {
                Ran::Process(r) => (r.run.metrics, Some(r.timing.summary())),
                Ran::Inproc(run) => (run.metrics, None),
            },
        )
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
