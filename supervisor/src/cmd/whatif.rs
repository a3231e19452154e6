//! `deltaloop whatif CONFIG --latency SOURCE`: the tracking a measured latency distribution would
//! cost each law, as a distribution over in-process replicas.

use super::words::Words;
use super::{Context, OutArgs};
use anyhow::Result;
use deltaloop_config::{Compensation, Law, RunConfig};
use deltaloop_report::RunFolder;
use deltaloop_studies::whatif::{self, DrawChoice, Request, source::Unit};
use std::path::PathBuf;

#[derive(clap::Args, Debug)]
pub struct Args {
    /// Scenario file (TOML), e.g. configs/s1-nominal.toml.
    config: PathBuf,
    /// Where the latencies come from (repeatable; pooled): a realtime run folder (its ticks'
    /// `arrival_ns`), an HdrHistogram file (`.hgrm` or `.hlog`), or a text file of latencies in
    /// µs, one per line.
    #[arg(long = "latency", value_name = "SOURCE", required = true)]
    latency: Vec<PathBuf>,
    /// Only this law (repeatable; default: the config's laws).
    #[arg(long = "law", value_parser = Words::<Law>::new())]
    laws: Vec<Law>,
    /// Delay compensation of the laws (controller.compensate): `none` or `predict` (default: the
    /// config's). A compensated law predicts over the config's transport delay, as in a run.
    #[arg(long, value_parser = Words::<Compensation>::new())]
    compensate: Option<Compensation>,
    /// Replicas per law (each a drawn latency sequence).
    #[arg(long, default_value_t = 200)]
    replicas: u64,
    /// Seed of the latency draws (sensor noise keeps the scenario's seed).
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Draw model (default: block for run folders and text files, independent when an
    /// HdrHistogram file is among the sources).
    #[arg(long, value_parser = Words::<DrawChoice>::new())]
    draw: Option<DrawChoice>,
    /// Block length of the block bootstrap, ticks (default 1000).
    #[arg(long)]
    block_ticks: Option<usize>,
    /// Replay one run folder's own sequence per law, in order (with --replicas 1): its trace.
    #[arg(long)]
    as_recorded: bool,
    /// Unit of a text file's latencies (default us), and of an HdrHistogram file that does not
    /// state its own.
    #[arg(long, value_parser = Words::<Unit>::new())]
    latency_unit: Option<Unit>,
    /// A text record's lines are one every P µs (a target's loop at another rate): each line
    /// then holds for P µs of the scenario's ticks, so a burst keeps its duration in time
    /// (default: one line per tick of the scenario).
    #[arg(long, value_name = "P")]
    record_period_us: Option<f64>,
    /// Also run with the latencies multiplied by these factors, e.g. 0.5,2,4 (1 always runs).
    #[arg(long, value_delimiter = ',', allow_negative_numbers = true)]
    scale: Vec<f64>,
    /// Write each replica's trace.csv under traces/.
    #[arg(long)]
    keep_traces: bool,
    #[command(flatten)]
    out: OutArgs,
}

pub fn exec(a: Args, cx: &Context) -> Result<()> {
    let mut cfg = RunConfig::from_file(&a.config)?;
    if !a.laws.is_empty() {
        // Checked as the file's own list is (regression: `--law tdc --law tdc` ran the law twice
        // and wrote its key twice into whatif.json).
        cfg.controller.laws = a.laws.clone();
        cfg.validate().map_err(|e| anyhow::anyhow!("--law: {e}"))?;
    }
    if let Some(c) = a.compensate {
        cfg.controller.compensate = c;
    }
    let dir = a
        .out
        .out
        .clone()
        .unwrap_or_else(|| deltaloop_report::default_run_dir(&format!("whatif-{}", cfg.name)));
    let sources: Vec<(&std::path::Path, &str)> =
        std::iter::once((a.config.as_path(), "the scenario file"))
            .chain(
                a.latency
                    .iter()
                    .map(|p| (p.as_path(), "a --latency source")),
            )
            .collect();
    let planned = whatif::plan(Request {
        config: cfg,
        config_path: &a.config,
        sources: &a.latency,
        unit: a.latency_unit,
        record_period_us: a.record_period_us,
        draw: a.draw,
        block_ticks: a.block_ticks,
        as_recorded: a.as_recorded,
        replicas: a.replicas,
        seed: a.seed,
        scales: &a.scale,
        keep_traces: a.keep_traces,
        command: &cx.command_line,
    })?;
    // Claimed only once the inputs are good: a refused command empties no folder.
    let folder = RunFolder::claim_apart(&dir, a.out.force, &sources)?;
    let o = match whatif::run(planned, folder.path(), cx.tty) {
        Ok(o) => o,
        Err(e) => {
            folder.release_unused();
            return Err(e);
        }
    };
    for l in &o.table {
        println!("{l}");
    }
    println!("wrote {}", folder.path().display());
    Ok(())
}
