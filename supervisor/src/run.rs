//! `deltaloop run`: one scenario, one or more laws, one run folder.

use crate::analysis::mismatch;
use crate::inproc;
use crate::metrics::{self, LawMetrics};
use crate::output::{self, Summary};
use crate::record::LawRun;
use crate::report;
use crate::study::Study;
use anyhow::{Context, Result};
use deltaloop_protocol::{Law, RunConfig};
use std::path::{Path, PathBuf};

/// The loop transport.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Mode {
    /// Plant and controller libraries stepped together in one process.
    Inproc,
}

impl Mode {
    pub fn name(self) -> &'static str {
        match self {
            Mode::Inproc => "inproc",
        }
    }
}

/// What one `run` produced.
pub struct RunOutput {
    pub dir: PathBuf,
    pub metrics: Vec<LawMetrics>,
    pub table: String,
}

/// Loads a config and keeps only `laws` (all of the config's when empty).
pub fn load_config(path: &Path, laws: &[Law]) -> Result<RunConfig> {
    let mut cfg = RunConfig::from_file(path)?;
    if !laws.is_empty() {
        cfg.controller.laws = laws.to_vec();
    }
    Ok(cfg)
}

/// Runs every law of `cfg` in `mode` and writes the run folder `out` (default `runs/<time>-<name>`).
pub fn run(cfg: RunConfig, mode: Mode, out: Option<PathBuf>, command: &str) -> Result<RunOutput> {
    let started = output::now_utc();
    let study = Study::new(cfg).context("the scenario's reference leaves the robot's workspace")?;
    let laws = study.config.controller.laws.clone();
    let runs: Vec<LawRun> = match mode {
        Mode::Inproc => inproc::run_laws(&study, &laws),
    };
    let metrics: Vec<LawMetrics> = runs
        .iter()
        .map(|r| metrics::compute(r, &study.reference, &study.robot, &study.params))
        .collect();
    let mm = mismatch(&study.robot, &study.reference, &study.params);
    let cfg = &study.config;
    let summary = Summary {
        scenario: &cfg.name,
        mode: mode.name(),
        preset: cfg.controller.preset.name(),
        command,
        started_utc: started,
        ts_s: cfg.loop_.ts_s,
        ticks: study.reference.n,
        motion_duration_s: study.reference.duration,
        friction: cfg.plant.friction,
        tau_max_nm: cfg.plant.tau_max_nm,
        tde_delay_samples: cfg.controller.tde_delay_samples,
        controller: study.params,
        mismatch: &mm,
        laws: metrics.iter().map(|m| (m.law.as_str(), m)).collect(),
    };
    let md = report::markdown(cfg, mode.name(), command, &metrics, &mm);
    let dir = out.unwrap_or_else(|| output::default_run_dir(&cfg.name));
    output::write_run_folder(&dir, cfg, &summary, &runs, &study.reference, &md)?;
    let table = report::terminal_table(cfg, &metrics);
    Ok(RunOutput {
        dir,
        metrics,
        table,
    })
}
