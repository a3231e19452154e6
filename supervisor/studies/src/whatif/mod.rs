//! `deltaloop whatif`: what a measured latency distribution would cost the tracking, without the
//! hardware. Each replica draws a latency sequence from the pooled records ([`draw`]), runs the
//! scenario in-process with each reply applied at its drawn arrival by the realtime arrival rule,
//! and records the metrics a run records; the replicas' spread, per law, is the answer
//! ([`summary`]), written as `whatif.json`, `report.md` and a figure ([`report`]).

pub mod draw;
pub mod pairs;
mod report;
pub mod source;
pub mod summary;

use anyhow::{Context, Result, bail};
use deltaloop_config::{Law, RunConfig};
use deltaloop_report as output;
use deltaloop_runner::inproc;
use deltaloop_runner::lawrun::{self, Keep};
use deltaloop_runner::run::Cancelled;
use deltaloop_runner::signals;
use deltaloop_study::Study;
use draw::{AsRecorded, Drawn, Model, Pool};
use source::{Kind, Source, Unit};
use std::path::{Path, PathBuf};
use std::time::Instant;
pub use summary::{Sample, WhatIfJson};

/// The default block of the bootstrap, ticks: 0.3 s at 3.3 kHz, long enough to keep the bursts
/// a host's stalls make (tens of ms) whole, short enough that an S1 run (0.8 s) mixes blocks.
pub const DEFAULT_BLOCK_TICKS: usize = 1000;

deltaloop_names::text_enum! {
    "kebab-case", "draw model";
    /// Which draw model was asked for (`--draw`; None in [`Request::draw`]: the sources' default).
    pub enum DrawChoice {
        /// Blocks of consecutive recorded ticks (keeps bursts).
        Block,
        /// Every tick on its own from the pooled distribution.
        Independent,
    }
}

/// What to ask.
pub struct Request<'a> {
    pub config: RunConfig,
    pub config_path: &'a Path,
    /// The `--latency` sources, pooled.
    pub sources: &'a [PathBuf],
    /// The unit of HdrHistogram files that do not state theirs.
    pub unit: Option<Unit>,
    /// A text record's line period, µs (`--record-period-us`; None: one line per tick).
    pub record_period_us: Option<f64>,
    pub draw: Option<DrawChoice>,
    pub block_ticks: Option<usize>,
    /// Each law's own recorded sequence, in order (one run folder, one replica).
    pub as_recorded: bool,
    pub replicas: u64,
    /// Seeds the latency draws only.
    pub seed: u64,
    /// Latency multipliers (1 is always run).
    pub scales: &'a [f64],
    pub keep_traces: bool,
    pub command: &'a str,
}

/// A what-if checked and loaded, ready to run: every input error is found before anything is
/// written.
pub struct Planned<'a> {
    req: Request<'a>,
    study: Study,
    sources: Vec<Source>,
    model: Model,
    pool: Pool,
    scales: Vec<f64>,
}

/// What `whatif` found.
pub struct Outcome {
    pub json: WhatIfJson,
    /// The per-law table, for the terminal.
    pub table: Vec<String>,
}

/// The largest replica count.
pub const MAX_REPLICAS: u64 = 1_000_000;

/// Checks the request and loads its sources.
pub fn plan(req: Request<'_>) -> Result<Planned<'_>> {
    if !(1..=MAX_REPLICAS).contains(&req.replicas) {
        bail!("--replicas = {}: expected 1..={MAX_REPLICAS}", req.replicas);
    }
    if let Some(&s) = req
        .scales
        .iter()
        .find(|s| !(s.is_finite() && **s > 0.0 && **s <= 1000.0))
    {
        bail!("--scale {s}: expected a number in (0, 1000]");
    }
    if req.block_ticks == Some(0) {
        bail!("--block-ticks = 0: expected at least 1 tick");
    }
    let mut sources = req
        .sources
        .iter()
        .map(|p| Source::load(p, req.unit))
        .collect::<Result<Vec<_>>>()?;
    if let Some(p) = req.record_period_us {
        source::at_period(&mut sources, p, req.config.loop_.ts_s * 1e6)?;
    }
    let model = model_of(&req, &sources)?;
    let mut scales = vec![1.0];
    for &s in req.scales {
        if !scales.contains(&s) {
            scales.push(s);
        }
    }
    scales.sort_by(f64::total_cmp);
    if model == Model::AsRecorded && scales.len() > 1 {
        bail!("--as-recorded replays the record as it was: it takes no --scale");
    }
    let study = Study::new(req.config.clone()).context("the scenario")?;
    let laws = study.config.controller.laws.clone();
    if model == Model::AsRecorded {
        for &law in &laws {
            if !sources[0].laws.contains(&law) {
                bail!(
                    "--as-recorded: {} has no ticks of law `{law}` (it recorded {}); choose the laws with --law",
                    sources[0].path.display(),
                    names(&sources[0].laws)
                );
            }
        }
    }
    for src in &sources {
        if let Some(rec) = &src.recorded {
            check_recorded(&study.config, rec, &src.path, model)?;
        }
    }
    let pool = Pool::new(&mut sources, model)?;
    Ok(Planned {
        req,
        study,
        sources,
        model,
        pool,
        scales,
    })
}

/// A run folder's config against the scenario: `--as-recorded` replays the run, so the scenario
/// must be the run's (but for the laws, which `--law` picks among, and the free-text
/// description); a drawn record's verdicts (late, missed) were made at its period and budget,
/// so those must be the scenario's (regression: S1's 2668 rows ran `--as-recorded` as S2, which
/// has 668).
fn check_recorded(cfg: &RunConfig, rec: &RunConfig, path: &Path, model: Model) -> Result<()> {
    let mut rec = rec.clone();
    rec.controller.laws.clone_from(&cfg.controller.laws);
    rec.description.clone_from(&cfg.description);
    let (mine, theirs) = (serde_json::to_value(cfg)?, serde_json::to_value(&rec)?);
    let keys: &[&str] = match model {
        Model::AsRecorded => &[""],
        _ => &["loop.ts_s", "loop.torque_budget_us"],
    };
    for key in keys {
        let (mut a, mut b) = (&mine, &theirs);
        for part in key.split('.').filter(|p| !p.is_empty()) {
            (a, b) = (&a[part], &b[part]);
        }
        if let Some((rest, a, b)) = first_difference(a, b) {
            let at = [*key, rest.as_str()]
                .into_iter()
                .filter(|k| !k.is_empty())
                .collect::<Vec<_>>()
                .join(".");
            bail!(
                "--latency {}: its config.toml has {at} = {b} where the scenario has {a}: {}",
                path.display(),
                match model {
                    Model::AsRecorded =>
                        "--as-recorded replays that run: give its config.toml as CONFIG",
                    _ =>
                        "its late and missed ticks were judged at its own period and budget: record at the scenario's",
                }
            );
        }
    }
    Ok(())
}

/// The first place where two JSON values differ: (dotted key, "" at the top; a; b).
fn first_difference(
    a: &serde_json::Value,
    b: &serde_json::Value,
) -> Option<(String, String, String)> {
    use serde_json::Value;
    let null = Value::Null;
    match (a, b) {
        (Value::Object(x), Value::Object(y)) => x
            .keys()
            .chain(y.keys().filter(|k| !x.contains_key(*k)))
            .find_map(|k| {
                let (p, q) = (x.get(k).unwrap_or(&null), y.get(k).unwrap_or(&null));
                first_difference(p, q).map(|(rest, p, q)| {
                    let at = if rest.is_empty() {
                        k.clone()
                    } else {
                        format!("{k}.{rest}")
                    };
                    (at, p, q)
                })
            }),
        _ if a == b => None,
        _ => Some((String::new(), a.to_string(), b.to_string())),
    }
}

/// How many times each law's in-process run is timed for the speed baseline (the median counts).
const BASELINE_RUNS: usize = 9;

/// Runs a planned what-if into `out` (claimed by the caller); `progress` draws a bar on stderr.
/// Ctrl-C / SIGTERM stop it within a replica's tick ([`Cancelled`]); then, as on any error, it
/// leaves nothing in `out` (no `whatif.json` unless every replica ran, no `traces/`).
pub fn run(p: Planned<'_>, out: &Path, progress: bool) -> Result<Outcome> {
    let result = run_all(p, out, progress);
    if result.is_err() {
        let _ = std::fs::remove_dir_all(out.join("traces"));
    }
    result
}

/// Whether Ctrl-C / SIGTERM asked the what-if to stop: Err to return if so.
fn go_on() -> Result<()> {
    if signals::interrupted() {
        return Err(anyhow::Error::new(Cancelled("whatif".into())));
    }
    Ok(())
}

fn run_all(p: Planned<'_>, out: &Path, progress: bool) -> Result<Outcome> {
    let Planned {
        req,
        study,
        sources,
        model,
        pool,
        scales,
    } = p;
    let laws = study.config.controller.laws.clone();
    let budget_ns = u64::from(study.config.loop_.torque_budget_us) * 1000;
    let last = study.reference.n as u64;

    // The baseline the speed is judged against: one in-process run of each law, timed here.
    // The median of a few, after one untimed: the first run of a process pays for its page
    // faults.
    let mut one_run_s = Vec::new();
    let mut ideal = Vec::new();
    for &law in &laws {
        // Each run checked: an interrupted one is short, its RMS not the ideal's.
        let first = inproc::run_law(&study, law, &Keep::default())?;
        go_on()?;
        ideal.push(deltaloop_runner::replay::max_rms(&first.metrics));
        let mut t: Vec<f64> = (0..BASELINE_RUNS)
            .map(|_| {
                let t0 = Instant::now();
                let run = inproc::run_law(&study, law, &Keep::default());
                go_on()?;
                run.map(|_| t0.elapsed().as_secs_f64())
            })
            .collect::<Result<_>>()?;
        t.sort_by(f64::total_cmp);
        one_run_s.push(t[BASELINE_RUNS / 2]);
    }

    // Job i is law l of replica r at scale s, in that order; not listed up front (a million
    // replicas took seconds to list before a signal could stop them).
    let nl = laws.len();
    let per_scale = req.replicas as usize * nl;
    let jobs = scales.len() * per_scale;
    let job = |i: usize| (i / per_scale, ((i % per_scale) / nl) as u64, i % nl);
    let traces_dir = |s: usize, r: u64| -> PathBuf {
        let d = out.join("traces");
        let d = if scales.len() > 1 {
            d.join(format!("x{}", summary::scale_key(scales[s])))
        } else {
            d
        };
        d.join(format!("{r:04}"))
    };
    if req.keep_traces {
        for s in 0..scales.len() {
            for r in 0..req.replicas {
                go_on()?;
                let d = traces_dir(s, r);
                std::fs::create_dir_all(&d)
                    .with_context(|| format!("cannot create {}", d.display()))?;
            }
        }
    }
    let threads = std::thread::available_parallelism().map_or(1, |n| n.get());
    let bar = output::progress_bar(jobs, progress);
    bar.set_message("replicas");
    let t0 = Instant::now();
    // After Ctrl-C no job starts (a million of them, each returning an error with its
    // backtrace, took minutes).
    let samples = deltaloop_runner::pool::map_until(jobs, threads, signals::interrupted, |i| {
        let (s, r, l) = job(i);
        let law = laws[l];
        let keep = Keep {
            trace: req
                .keep_traces
                .then(|| output::trace_part(&traces_dir(s, r), law)),
            ..Keep::default()
        };
        let out = (|| -> Result<Sample> {
            let rec = lawrun::recorder(&study, law, &keep)?;
            let plant = study.plant_side().context("the initial configuration")?;
            let (run, misses) = match model {
                Model::AsRecorded => {
                    let mut sched = AsRecorded {
                        seq: sources[0].sequence_of(law),
                        misses: 0,
                    };
                    let run = inproc::run_schedule(&study, law, rec, plant, &mut sched)?;
                    (run, sched.misses)
                }
                _ => {
                    let mut sched =
                        Drawn::new(&pool, model, req.seed, r, scales[s], budget_ns, last);
                    let run = inproc::run_schedule(&study, law, rec, plant, &mut sched)?;
                    (run, sched.misses)
                }
            };
            Ok(Sample::of(&run.metrics, misses))
        })();
        bar.inc(1);
        out
    });
    bar.finish_and_clear();
    let wall_s = t0.elapsed().as_secs_f64();
    // A job not run means a signal came, which `go_on` reports first.
    go_on()?;
    if samples.len() != jobs {
        bail!("{} of {jobs} replicas ran", samples.len());
    }
    let samples = samples
        .into_iter()
        .map(|(_, s)| s)
        .collect::<Result<Vec<Sample>>>()?;
    if req.keep_traces {
        for s in 0..scales.len() {
            for r in 0..req.replicas {
                go_on()?;
                output::join_trace(&traces_dir(s, r), &laws)?;
            }
        }
    }

    let json = summary::summarize(summary::Inputs {
        study: &study,
        config_path: req.config_path,
        command: req.command,
        sources: &sources,
        model,
        pool: &pool,
        seed: req.seed,
        replicas: req.replicas,
        laws: &laws,
        scales: &scales,
        samples: &samples,
        ideal: &ideal,
        one_run_s: &one_run_s,
        wall_s,
        threads,
    });
    output::write_whole(
        &out.join("whatif.json"),
        (serde_json::to_string_pretty(&json)? + "\n").as_bytes(),
    )?;
    report::figure(&out.join("whatif"), &json, &pool, &samples, &laws, &scales)?;
    output::write_text(&out.join("report.md"), &report::markdown(&json))?;
    Ok(Outcome {
        table: report::table(&json),
        json,
    })
}

/// The draw model the request and its sources make.
fn model_of(req: &Request<'_>, sources: &[Source]) -> Result<Model> {
    if req.as_recorded {
        if sources.len() != 1 || sources[0].kind != Kind::RunFolder {
            bail!("--as-recorded replays one run folder: give exactly one --latency RUN_DIR");
        }
        if req.replicas != 1 {
            bail!(
                "--as-recorded draws nothing, so every replica would be the same: use --replicas 1 (got {})",
                req.replicas
            );
        }
        if req.draw.is_some() || req.block_ticks.is_some() {
            bail!("--as-recorded draws nothing: it takes no --draw or --block-ticks");
        }
        return Ok(Model::AsRecorded);
    }
    let ordered = sources
        .iter()
        .all(|s| matches!(s.latencies, source::Latencies::Sequences(_)));
    let choice = req.draw.unwrap_or(if ordered {
        DrawChoice::Block
    } else {
        DrawChoice::Independent
    });
    Ok(match choice {
        DrawChoice::Block => Model::Block {
            ticks: req.block_ticks.unwrap_or(DEFAULT_BLOCK_TICKS),
        },
        DrawChoice::Independent => {
            if req.block_ticks.is_some() {
                bail!(
                    "--block-ticks is for the block bootstrap (--draw block), not independent draws"
                );
            }
            Model::Independent
        }
    })
}

fn names(laws: &[Law]) -> String {
    laws.iter()
        .map(|l| format!("`{l}`"))
        .collect::<Vec<_>>()
        .join(", ")
}
