//! One point of a sweep: its config, its run (through the same code as `deltaloop run`), and
//! its row of `sweep.csv` with the status the run ended in.

use super::schema::Job;
use crate::loops::lawrun::Keep;
use crate::loops::{self, Ran};
use crate::record::RunStatus;
use crate::record::metrics::LawMetrics;
use crate::study::Study;
use anyhow::{Context, Result};
use deltaloop_config::config::PathKind;
use deltaloop_config::{Law, LoopMode, Preset, RunConfig};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// One grid point's result: a row of `sweep.csv`.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Row {
    /// The point's id in the plan (see [`super::plan::Plan`]).
    pub point: String,
    pub scenario: PathKind,
    pub preset: Preset,
    pub law: Law,
    pub mode: LoopMode,
    pub tde_delay_samples: u32,
    pub transport_delay_samples: u32,
    /// The sub-tick transport delay, µs (the delay D is d·Ts plus this).
    pub transport_delay_us: f64,
    /// The effective estimation delay L_eff/Ts = ℓ + D/Ts, ticks.
    pub effective_delay_ticks: f64,
    pub compute_delay_us: u32,
    /// How the point ended: the run's [`RunStatus`] (`error`: the point could not run).
    pub status: RunStatus,
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

impl Row {
    /// Whether the row is a result (every status but `interrupted`: a point cut short by
    /// Ctrl-C / SIGTERM measured nothing complete).
    pub fn is_result(&self) -> bool {
        self.status != RunStatus::Interrupted
    }
}

/// A metric read off a row.
pub(super) type Metric = fn(&Row) -> f64;

pub(super) fn maxj(v: [f64; 3]) -> f64 {
    v.into_iter().fold(0.0, f64::max)
}

/// Status and reason of a point (see [`Row::status`]): the run's own (see
/// [`RunEnd::status`](crate::record::RunEnd::status)), or `error` with the error.
pub(super) fn status(m: Option<&LawMetrics>, err: Option<&str>) -> (RunStatus, String) {
    match (m, err) {
        (Some(m), None) => (m.status, m.reason.clone().unwrap_or_default()),
        (Some(_), Some(e)) => (RunStatus::Error, e.to_string()),
        (None, e) => {
            let e = e.filter(|e| !e.is_empty()).unwrap_or("no result");
            (RunStatus::Error, e.to_string())
        }
    }
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
