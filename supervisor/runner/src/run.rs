//! `deltaloop run`: one scenario, one or more laws, one run folder.

use crate::inproc;
use crate::lawrun::{Keep, LawRun, Tap};
use crate::procs::{self, OnTick};
use anyhow::{Context, Result, bail};
use deltaloop_config::{Compensation, DelaySource, Law, LoopMode, Overrun, RunConfig};
use deltaloop_report::report;
use deltaloop_report::{self as output, Summary};
use deltaloop_study::Study;
use deltaloop_study::analysis::mismatch;
use deltaloop_study::record::metrics::LawMetrics;
use deltaloop_study::record::{Fault, RunStatus};
use deltaloop_timing::{PeakRss, Timing, TimingSummary};
use deltaloop_transport::ipc;
use std::path::{Path, PathBuf};

/// What one `run` produced.
pub struct RunOutput {
    pub dir: PathBuf,
    pub metrics: Vec<LawMetrics>,
    pub table: String,
    /// Lines for the user: scheduling warnings, cleaned stale resources.
    pub notes: Vec<String>,
    /// What was run, and the runs themselves (their records only if asked for, for figures).
    pub study: Study,
    pub runs: Vec<LawRun>,
    /// The peak memory of the last process run's processes (None: inproc).
    pub peak_rss: Option<PeakRss>,
}

impl RunOutput {
    /// The notes on stderr, the table and the run folder on stdout. Never panics on a closed
    /// terminal or pipe: the run folder is already written.
    pub fn print(&self) {
        use std::io::Write;
        for n in &self.notes {
            let _ = writeln!(std::io::stderr(), "{n}");
        }
        let mut out = std::io::stdout().lock();
        let _ = write!(out, "{}", self.table);
        let _ = writeln!(out, "run folder: {}", self.dir.display());
    }
}

/// Overrides of a scenario file, as `run` and `soak` take them (None: keep the file's value).
#[derive(Clone, Debug, Default)]
pub struct Overrides {
    /// Run only this law (repeatable): tdc, tde-is, tdc-is-sta, tdc-is-ista, pid.
    pub laws: Vec<Law>,
    /// TDE delay ℓ in ticks (controller.tde_delay_samples).
    pub tde_delay: Option<u32>,
    /// Transport delay d in ticks (plant.transport_delay_samples).
    pub transport_delay: Option<u32>,
    /// Transport delay beyond whole ticks, µs (plant.transport_delay_us; adds to --transport-delay).
    pub transport_delay_us: Option<f64>,
    /// Extra controller compute time per tick, µs (controller.compute_delay_us; realtime).
    pub compute_delay_us: Option<u32>,
    /// Delay compensation (controller.compensate): none, or predict.
    pub compensate: Option<Compensation>,
    /// The delay D₀ a compensated law assumes, µs (controller.compensate_delay_us).
    pub compensate_delay_us: Option<f64>,
    /// Where a compensated law's delay comes from (controller.compensate_delay).
    pub compensate_delay: Option<DelaySource>,
    /// Sensor noise seed (sensor.seed).
    pub seed: Option<u64>,
    /// Realtime: what the plant does when its own process wakes later than
    /// loop.overrun_after_us (default one tick): stretch (pause simulated time for the stall),
    /// catch-up (run the backlog on the wall clock) or fault (stop the run) (loop.overrun).
    pub overrun: Option<Overrun>,
    /// Hold at the end point after the motion, s (scenario.hold_s, 0..=86400).
    pub hold_s: Option<f64>,
    /// Run this command in place of the built-in plant process (plant.command; split at
    /// whitespace: put arguments with spaces in the scenario file's array).
    pub plant_cmd: Option<String>,
    /// Run this command in place of the built-in controller process (controller.command).
    pub controller_cmd: Option<String>,
    /// What the run calls its controller (controller.label).
    pub controller_label: Option<String>,
    /// A ROS 2 node is the controller: `deltaloop-ros2-robot` in the controller's place
    /// (`--controller ros2`; `[ros2]` added with its defaults if the file has none).
    pub ros2_controller: bool,
    /// Publish the run's live topics (`--ros2`; `[ros2]` added likewise).
    pub ros2: bool,
    /// Name the cause of each missed or late tick (`--explain`: record.explain).
    pub explain: bool,
    pub remote: crate::join::RemoteArgs,
}

impl Overrides {
    /// The flags that name a process need a mode with processes: in `--mode inproc` the laws
    /// run inside the supervisor, and the process a flag names would silently not run.
    pub fn check_mode(&self, mode: LoopMode) -> Result<()> {
        self.remote.check_mode(mode)?;
        if mode.is_process() {
            return Ok(());
        }
        let flag = if self.ros2_controller {
            "--controller ros2"
        } else if self.controller_cmd.is_some() {
            "--controller-cmd"
        } else if self.plant_cmd.is_some() {
            "--plant-cmd"
        } else {
            return Ok(());
        };
        bail!(
            "{flag} with --mode {}: it names a process, and inproc runs none (allowed: --mode lockstep or realtime)",
            mode.name()
        )
    }

    /// Applies the overrides and validates the result (same errors as the file would give).
    pub fn apply(&self, mut cfg: RunConfig) -> Result<RunConfig> {
        if !self.laws.is_empty() {
            cfg.controller.laws = self.laws.clone();
        }
        if let Some(v) = self.tde_delay {
            cfg.controller.tde_delay_samples = v;
        }
        if let Some(v) = self.transport_delay {
            cfg.plant.transport_delay_samples = v;
        }
        if let Some(v) = self.transport_delay_us {
            cfg.plant.transport_delay_us = v;
        }
        if let Some(v) = self.compute_delay_us {
            cfg.controller.compute_delay_us = v;
        }
        if let Some(v) = self.compensate {
            cfg.controller.compensate = v;
        }
        if let Some(v) = self.compensate_delay_us {
            cfg.controller.compensate_delay_us = Some(v);
        }
        if let Some(v) = self.compensate_delay {
            cfg.controller.compensate_delay = v;
        }
        if let Some(v) = self.seed {
            cfg.sensor.seed = v;
        }
        if let Some(v) = self.overrun {
            cfg.loop_.overrun = v;
        }
        if let Some(v) = self.hold_s {
            cfg.scenario.hold_s = v;
        }
        cfg.record.explain |= self.explain;
        let words = |c: &str| c.split_whitespace().map(str::to_string).collect::<Vec<_>>();
        if let Some(c) = &self.plant_cmd {
            cfg.plant.command = words(c);
        }
        if let Some(c) = &self.controller_cmd {
            cfg.controller.command = words(c);
        }
        if let Some(l) = &self.controller_label {
            cfg.controller.label = l.clone();
        }
        if self.ros2_controller {
            if self.controller_cmd.is_some() {
                bail!("--controller ros2 and --controller-cmd both name the controller: give one");
            }
            let exe = procs::exe_dir()?.join(procs::ROS2_ROBOT);
            if !exe.is_file() {
                bail!(
                    "--controller ros2: {} is missing (deltaloop built without its `ros2` feature?)",
                    exe.display()
                );
            }
            cfg.controller.command = vec![exe.to_string_lossy().into_owned()];
            cfg.controller.label = "ros2".into();
        }
        if self.ros2 || self.ros2_controller {
            cfg.ros2.get_or_insert_default();
        }
        self.remote.apply(&mut cfg)?;
        cfg.validate()?;
        Ok(cfg)
    }
}

/// Loads a config and applies command-line overrides.
pub fn load_config(path: &Path, o: &Overrides) -> Result<RunConfig> {
    o.apply(RunConfig::from_file(path)?)
}

/// What [`load_config`] reads, each with what it is: the scenario file and the link key file
/// (for [`RunRequest::reads`]).
pub fn config_reads(path: &Path, o: &Overrides) -> Vec<(PathBuf, &'static str)> {
    let key = o.remote.link_key.clone().map(|k| (k, "the link key file"));
    std::iter::once((path.to_path_buf(), "the scenario file"))
        .chain(key)
        .collect()
}

/// The files a config's plant and controller commands name (words that name an existing file,
/// from the working directory: the program, a script), each with what it is: a run folder may
/// not hold them.
pub fn command_files(cfg: &RunConfig) -> Vec<(PathBuf, &'static str)> {
    let named = |cmd: &[String], what: &'static str| {
        cmd.iter()
            .filter(|w| Path::new(w).is_file())
            .map(move |w| (PathBuf::from(w), what))
            .collect::<Vec<_>>()
    };
    let mut v = named(&cfg.plant.command, "a file of the plant command");
    v.extend(named(
        &cfg.controller.command,
        "a file of the controller command",
    ));
    v
}

/// What to run: every law of a config in one mode, into one run folder. `deltaloop run`, the
/// paper and a soak all ask through it.
pub struct RunRequest<'a> {
    pub config: RunConfig,
    pub mode: LoopMode,
    /// The run folder (default `runs/<time>-<name>`): empty or new unless `force` (see
    /// [`output::RunFolder::claim`]).
    pub out: Option<PathBuf>,
    pub force: bool,
    /// What the command read (the scenario file, the link key, …; see [`config_reads`]), each
    /// with what it is. The run folder may not be, hold or lie inside any of them, nor any file
    /// the config's commands name, `force` or not ([`output::RunFolder::claim_apart`]).
    pub reads: Vec<(PathBuf, &'static str)>,
    /// Keep every tick's record in memory too (for figures of short runs); otherwise the ticks
    /// are only streamed to `trace.csv` (unless `record.trace = false`) and the metrics, and
    /// memory does not grow with the run.
    pub keep_records: bool,
    /// Run each law's round-off twin too (inproc and lockstep only; see
    /// [`deltaloop_study::record::sensitivity`]): every law's metrics get its spreads.
    pub sensitivity: bool,
    /// The command line, for `summary.json` and `report.md`.
    pub command: &'a str,
    /// Sees every tick the process modes finish, in tick order (see [`procs::OnTick`]).
    pub on_tick: Option<OnTick<'a>>,
    /// Also write each law's `<law>.mcap` while it records ([`output::mcap::Live`]).
    pub mcap: bool,
    /// Also hand each law's finished ticks to this sink (the ROS 2 live topics).
    pub tap: Option<Tap>,
}

impl<'a> RunRequest<'a> {
    /// A request for `config` in `mode` into the default folder, nothing else asked for.
    pub fn new(config: RunConfig, mode: LoopMode, command: &'a str) -> Self {
        Self {
            config,
            mode,
            out: None,
            force: false,
            reads: Vec::new(),
            keep_records: false,
            sensitivity: false,
            command,
            on_tick: None,
            mcap: false,
            tap: None,
        }
    }
}

/// The laws' runs, in order, and how the sequence ended.
#[derive(Default)]
struct Laws {
    runs: Vec<LawRun>,
    /// Per run: its loop timing (None: inproc).
    timings: Vec<Option<Timing>>,
    run_ids: Vec<(Law, String)>,
    /// What the controller called itself (its READY), the first that did.
    controller_said: Option<String>,
    /// Each law whose plant once woke ten ticks late or more (realtime): see Timing::freeze_note.
    freezes: Vec<(Law, String)>,
    /// A fault or an interrupt ends the run after this law; the folder is still written.
    stopped: Option<(Law, Option<Fault>)>,
    failed: Option<anyhow::Error>,
}

/// Runs every law of the request and writes its run folder.
pub fn run(req: RunRequest<'_>) -> Result<RunOutput> {
    let RunRequest {
        config,
        mode,
        out,
        force,
        mut reads,
        keep_records,
        sensitivity,
        command,
        mut on_tick,
        mcap,
        tap,
    } = req;
    if sensitivity && mode == LoopMode::Realtime {
        bail!(
            "--sensitivity needs mode inproc or lockstep: a realtime run's timing is not repeatable, so its twin would differ by more than round-off"
        );
    }
    if sensitivity && !(config.plant.command.is_empty() && config.controller.command.is_empty()) {
        bail!(
            "--sensitivity runs each law's twin with the built-in plant and controller: it cannot repeat a run with plant.command or controller.command"
        );
    }
    let started = output::now_utc();
    let study =
        Study::new(config).context("the scenario's reference leaves the robot's workspace")?;
    let cfg = &study.config;
    reads.extend(command_files(cfg));
    let folder = output::RunFolder::claim_apart(
        &out.unwrap_or_else(|| output::default_run_dir(&cfg.name)),
        force,
        &reads,
    )?;
    let dir = folder.path().to_path_buf();
    // The resolved config goes first, and only here: the child processes read it, and it
    // documents a failed run. write_run_folder adds the results next to it.
    output::write_text(&dir.join("config.toml"), &cfg.to_toml_string())?;
    let mut notes = Vec::new();
    if cfg.controller.compute_delay_us > 0 && mode != LoopMode::Realtime {
        notes.push(format!(
            "note: compute_delay_us = {} only changes results in realtime mode ({} mode ignores it{})",
            cfg.controller.compute_delay_us,
            mode.name(),
            if mode == LoopMode::Lockstep { " except for wall time" } else { "" }
        ));
    }
    let keep = |law: Law| Keep {
        trace: cfg.record.trace.then(|| output::trace_part(&dir, law)),
        records: keep_records,
        mcap: mcap.then(|| dir.join(format!("{law}.mcap"))),
        tap: tap.clone(),
    };
    let mut laws = match mode {
        LoopMode::Inproc => run_inproc(&study, keep),
        pm => run_processes(&study, pm, &dir, keep, &mut on_tick, &mut notes),
    };
    if sensitivity && laws.failed.is_none() {
        add_sensitivity(&study, &mut laws.runs)?;
        notes.extend(
            deltaloop_study::record::sensitivity::masked_note(&study.config)
                .map(|n| format!("note: {n}")),
        );
    }
    let peak_rss = laws
        .timings
        .iter()
        .rev()
        .flatten()
        .next()
        .map(|t| t.peak_rss.clone());
    let metrics: Vec<LawMetrics> = laws.runs.iter().map(|r| r.metrics.clone()).collect();
    let table = write_results(&study, mode, command, started, &dir, &laws, &metrics)
        .map_err(|w| incomplete(&mut laws, &dir, w))?;
    verdict(mode, &dir, &mut laws, &metrics)?;
    notes.extend(laws.freezes.into_iter().map(|(l, f)| format!("`{l}`: {f}")));
    Ok(RunOutput {
        dir,
        metrics,
        table,
        notes,
        study,
        runs: laws.runs,
        peak_rss,
    })
}

/// Runs each law's round-off twins (in-process, on every core) and files the spreads
/// with the law's metrics. In lockstep too the twin runs in-process: the two modes give the
/// same bits.
fn add_sensitivity(study: &Study, runs: &mut [LawRun]) -> Result<()> {
    // A run the loop cut short (a fault, an interrupt, lost data) is not the run its twin
    // repeats: comparing them would call the cut round-off.
    let mut physical: Vec<&mut LawRun> = runs
        .iter_mut()
        .filter(|r| r.metrics.status.is_physical())
        .collect();
    let laws: Vec<Law> = physical.iter().map(|r| r.law).collect();
    for (run, twins) in physical.iter_mut().zip(inproc::run_twins(study, &laws)) {
        let twins = twins.context("the round-off twins")?;
        run.metrics.sensitivity = run.metrics.against_twins(&twins);
    }
    Ok(())
}

/// Every law in-process, each on its own thread.
fn run_inproc(study: &Study, keep: impl Fn(Law) -> Keep) -> Laws {
    let mut laws = Laws::default();
    for r in inproc::run_laws(study, &study.config.controller.laws, keep) {
        match r {
            Ok(r) => laws.runs.push(r),
            Err(e) => {
                laws.failed.get_or_insert(e);
            }
        }
    }
    laws.timings = vec![None; laws.runs.len()];
    laws
}

/// Every law with a process pair, one after the other, until one stops or fails.
fn run_processes(
    study: &Study,
    mode: LoopMode,
    dir: &Path,
    keep: impl Fn(Law) -> Keep,
    on_tick: &mut Option<OnTick<'_>>,
    notes: &mut Vec<String>,
) -> Laws {
    let cfg = &study.config;
    let removed = ipc::remove_dead_nodes();
    if !removed.is_empty() {
        notes.push(format!(
            "removed stale iceoryx2 resources of {} dead node(s): {}",
            removed.len(),
            removed.join(", ")
        ));
    }
    let mut laws = Laws::default();
    for &law in &cfg.controller.laws {
        if laws.stopped.is_some() || crate::signals::interrupted() {
            break;
        }
        // A law that fails to run (or to write its files: a full disk) ends the run, but
        // the laws before it still get their trace, summary and report.
        let tick = on_tick.as_mut().map(|f| -> OnTick<'_> { &mut **f });
        let r = match procs::run_law(study, law, mode, dir, &keep(law), tick) {
            Ok(r) => r,
            Err(e) => {
                laws.failed = Some(e.context(format!("{} run of `{law}`", mode.name())));
                break;
            }
        };
        for m in r.child_messages {
            if !notes.contains(&m) {
                notes.push(m);
            }
        }
        let files = r.timing.write_hgrm(dir, &format!("{law}.")).and_then(|()| {
            deltaloop_report::plot::timing_figures(
                dir,
                &format!("{law}."),
                &format!("{law}, {}", mode.name()),
                &r.timing,
                f64::from(cfg.loop_.torque_budget_us),
            )
        });
        if let Err(e) = files {
            laws.failed = Some(e.context(format!("{} run of `{law}`", mode.name())));
        }
        if let Some(n) = r.timing.freeze_note() {
            laws.freezes.push((law, n));
        }
        laws.run_ids.push((law, r.run_id));
        if laws.controller_said.is_none() {
            laws.controller_said = r.controller_label;
        }
        if r.interrupted || r.fault.is_some() {
            laws.stopped = Some((law, r.fault.clone()));
        }
        laws.runs.push(r.run);
        laws.timings.push(Some(r.timing));
        if laws.failed.is_some() {
            break;
        }
    }
    laws
}

/// Writes `summary.json`, `report.md` and the trace of the run folder; returns the terminal
/// table.
fn write_results(
    study: &Study,
    mode: LoopMode,
    command: &str,
    started: String,
    dir: &Path,
    laws: &Laws,
    metrics: &[LawMetrics],
) -> Result<String> {
    let cfg = &study.config;
    let timing_summaries: Vec<Option<TimingSummary>> = laws
        .timings
        .iter()
        .map(|t| t.as_ref().map(Timing::summary))
        .collect();
    let mm = mismatch(&study.robot, &study.reference, &study.params);
    let label = report::controller_label(cfg, mode, laws.controller_said.as_deref());
    let summary = Summary {
        scenario: &cfg.name,
        mode,
        controller_label: label.as_deref(),
        preset: cfg.controller.preset,
        command,
        started_utc: started,
        ts_s: cfg.loop_.ts_s,
        ticks: study.reference.n,
        motion_duration_s: study.reference.duration,
        friction: cfg.plant.friction,
        tau_max_nm: cfg.plant.tau_max_nm,
        tde_delay_samples: cfg.controller.tde_delay_samples,
        compensate: cfg.controller.compensate,
        controller: study.params,
        mismatch: &mm,
        interrupted: crate::signals::interrupted(),
        laws: metrics.iter().map(|m| (m.law, m)).collect(),
        run_ids: laws
            .run_ids
            .iter()
            .map(|(l, id)| (*l, id.as_str()))
            .collect(),
        timing: metrics
            .iter()
            .zip(&timing_summaries)
            .filter_map(|(m, t)| t.as_ref().map(|t| (m.law, t)))
            .collect(),
    };
    let mut md = report::markdown(cfg, mode, label.as_deref(), command, metrics, &mm);
    if mode.is_process() {
        md.push_str(&report::timing_markdown(
            cfg,
            mode,
            metrics,
            &timing_summaries,
        ));
    }
    for (law, f) in &laws.freezes {
        md.push_str(&format!("\n**Frozen loop**: `{law}`: {f}.\n"));
    }
    if mode == LoopMode::Realtime && !metrics.is_empty() {
        md.push_str(&latency_cost_markdown(study, metrics)?);
    }
    // `trace.csv` holds whole laws: one that failed (a full disk) keeps what it wrote apart.
    let traced: Vec<Law> = laws.runs.iter().map(|r| r.law).collect();
    for &law in cfg.controller.laws.iter().filter(|l| !traced.contains(l)) {
        output::trace::keep_apart(dir, law);
    }
    output::write_run_folder(dir, &summary, cfg.record.trace.then_some(&traced[..]), &md)?;
    let mut table = report::terminal_table(cfg, label.as_deref(), metrics);
    if mode.is_process() {
        table.push_str(&report::timing_table(metrics, &timing_summaries));
    }
    Ok(table)
}

/// The run's error, if it has one: a law that failed, a fault or an interrupt, lost data.
fn verdict(mode: LoopMode, dir: &Path, laws: &mut Laws, metrics: &[LawMetrics]) -> Result<()> {
    if let Some(e) = laws.failed.take() {
        let finished: Vec<Law> = laws.runs.iter().map(|r| r.metrics.law).collect();
        return Err(e.context(kept_note(&finished, dir, &child_logs(dir))));
    }
    if let Some((law, fault)) = &laws.stopped {
        // A fault right after the loop froze is the machine's: say so on the same line.
        let frozen = laws
            .freezes
            .iter()
            .find(|(l, _)| l == law)
            .map_or(String::new(), |(l, f)| format!("; before it, `{l}`: {f}"));
        return Err(match fault {
            Some(f) => anyhow::Error::new(Ended {
                status: f.kind.status(),
                message: format!(
                    "{} run of `{law}` stopped by a fault: {}{frozen} (data so far in {})",
                    mode.name(),
                    f.cause,
                    dir.display()
                ),
            }),
            None => anyhow::Error::new(Interrupted(dir.to_path_buf())),
        });
    }
    if crate::signals::interrupted() {
        return Err(anyhow::Error::new(Interrupted(dir.to_path_buf())));
    }
    if let Some(m) = metrics.iter().find(|m| m.status == RunStatus::LostData) {
        return Err(anyhow::Error::new(Ended {
            status: m.status,
            message: format!(
                "{} run of `{}` lost data: {} (in {})",
                mode.name(),
                m.law,
                m.lost_data.as_deref().unwrap_or_default(),
                dir.display()
            ),
        }));
    }
    Ok(())
}

/// The error of a run whose folder could not be written whole (`w` names the files it lacks):
/// a law that failed first (on a full disk, the files after it fail too) stays the cause, and
/// what the folder keeps is said between the two.
fn incomplete(laws: &mut Laws, dir: &Path, w: anyhow::Error) -> anyhow::Error {
    let Some(e) = laws.failed.take() else {
        return w;
    };
    let finished: Vec<Law> = laws.runs.iter().map(|r| r.metrics.law).collect();
    if finished.is_empty() {
        return anyhow::anyhow!("{e:#}; {w:#}");
    }
    let kept = kept_note(&finished, dir, &[]);
    anyhow::anyhow!("{e:#}; {kept}, but {w:#}")
}

/// The children's stderr logs in a run folder (`<law>.plant.log`, …), sorted.
fn child_logs(dir: &Path) -> Vec<String> {
    let mut logs: Vec<String> = std::fs::read_dir(dir)
        .into_iter()
        .flatten()
        .flatten()
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| n.ends_with(".log"))
        .collect();
    logs.sort();
    logs
}

/// What a failed run's folder keeps: the laws that finished, or, when none did, what is there
/// (regression: "the laws that finished are kept in …" when none had).
fn kept_note(finished: &[Law], dir: &Path, logs: &[String]) -> String {
    if finished.is_empty() {
        format!(
            "no law finished: {} holds the resolved config.toml{}, and a summary and report without results{}",
            dir.display(),
            if logs.is_empty() {
                String::new()
            } else {
                format!(", the children's logs ({})", logs.join(", "))
            },
            rows_apart(&[], dir)
        )
    } else {
        let names: Vec<String> = finished.iter().map(Law::to_string).collect();
        format!(
            "the laws that finished ({}) are kept in {}{}",
            names.join(", "),
            dir.display(),
            rows_apart(&names, dir)
        )
    }
}

/// Where the rows of the laws that did not finish are (`trace.<law>.csv`, kept apart from
/// `trace.csv`), as the end of [`kept_note`]; empty if none.
fn rows_apart(finished: &[String], dir: &Path) -> String {
    let mut apart: Vec<String> = std::fs::read_dir(dir)
        .into_iter()
        .flatten()
        .flatten()
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| {
            n.strip_prefix("trace.")
                .and_then(|l| l.strip_suffix(".csv"))
                .is_some_and(|l| !finished.iter().any(|f| f == l))
        })
        .collect();
    apart.sort();
    if apart.is_empty() {
        return String::new();
    }
    format!(
        " (the rows of the laws that did not finish: {})",
        apart.join(", ")
    )
}

/// The report section that says what the measured latency cost: each law's tracking against the
/// same scenario with ideal timing (in-process, same config).
fn latency_cost_markdown(study: &Study, metrics: &[LawMetrics]) -> Result<String> {
    let mut md = String::from("\n## Measured latency cost\n\n");
    if crate::signals::interrupted() {
        // Ctrl-C asked for a prompt exit, and the in-process twin would stop at once too.
        md.push_str(if study.config.record.trace {
            "Not computed: the run was interrupted. `deltaloop replay <run folder> --ideal` computes it from the trace.\n"
        } else {
            "Not computed: the run was interrupted (and wrote no trace to compute it from later: `record.trace = false`).\n"
        });
        return Ok(md);
    }
    let measured: Vec<_> = metrics.iter().collect();
    let ticks: u64 = measured.iter().map(|m| m.ticks + 1).sum();
    if ticks > 1_000_000 {
        eprintln!("comparing with ideal timing: {ticks} ticks in-process ...");
    }
    let ideal = crate::replay::ideal_rms(study, &measured)?;
    md.push_str(
        "Each reply acted on the physics when it arrived (`apply_torque`); the same scenario with ideal timing (no latency, no misses) runs in-process over the same ticks for comparison. Max-joint RMS tracking error:\n\n",
    );
    for line in crate::replay::latency_cost(&measured, &ideal) {
        md.push_str(&format!("- {line}\n"));
    }
    md.push_str(
        "\nThis is one run: its timing is this run's. A sweep with `compute_delay_us = [0]` and `repeats = N` runs it N times and gives the cost's mean and 95 % confidence interval (docs/guide/trust.md).\n",
    );
    Ok(md)
}

/// The run was stopped by Ctrl-C / SIGTERM; its folder holds the data gathered so far.
#[derive(Debug)]
pub struct Interrupted(pub PathBuf);

impl std::fmt::Display for Interrupted {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "interrupted; the data gathered so far is in {}",
            self.0.display()
        )
    }
}

impl std::error::Error for Interrupted {}

/// A command stopped by Ctrl-C / SIGTERM whose result is whole or nothing (`whatif`): it wrote
/// none of it. The string names what was stopped.
#[derive(Debug)]
pub struct Cancelled(pub String);

impl std::fmt::Display for Cancelled {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{} interrupted before its end; nothing was written",
            self.0
        )
    }
}

impl std::error::Error for Cancelled {}

/// A run whose law ended with a status that fails the command (a fault, a stop on request, lost
/// data); its folder is written. The exit code comes from `status` (`cmd::exit_code`).
#[derive(Debug)]
pub struct Ended {
    pub status: RunStatus,
    /// One line for the user.
    pub message: String,
}

impl std::fmt::Display for Ended {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.message)
    }
}

impl std::error::Error for Ended {}

/// The status an error of [`run`] stands for: `interrupted`, the status of [`Ended`], or
/// `error` for any other failure.
pub fn error_status(e: &anyhow::Error) -> RunStatus {
    if e.downcast_ref::<Interrupted>().is_some() || e.downcast_ref::<Cancelled>().is_some() {
        RunStatus::Interrupted
    } else {
        e.downcast_ref::<Ended>()
            .map_or(RunStatus::Error, |e| e.status)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Regression: `--controller-cmd` with `--mode inproc` ran the built-in law and said nothing.
    #[test]
    fn regression_a_process_flag_in_inproc_is_refused() {
        let cases = [
            (
                Overrides {
                    controller_cmd: Some("python3 c.py".into()),
                    ..Overrides::default()
                },
                "--controller-cmd",
            ),
            (
                Overrides {
                    plant_cmd: Some("./plant".into()),
                    ..Overrides::default()
                },
                "--plant-cmd",
            ),
            (
                Overrides {
                    ros2_controller: true,
                    ..Overrides::default()
                },
                "--controller ros2",
            ),
        ];
        for (o, flag) in cases {
            let e = o.check_mode(LoopMode::Inproc).unwrap_err().to_string();
            assert!(
                e.starts_with(&format!("{flag} with --mode inproc"))
                    && e.contains("allowed: --mode lockstep or realtime"),
                "{e}"
            );
            o.check_mode(LoopMode::Lockstep).unwrap();
            o.check_mode(LoopMode::Realtime).unwrap();
        }
        Overrides::default().check_mode(LoopMode::Inproc).unwrap();
    }

    /// Regression: a run whose first law failed to start said "the laws that finished are kept
    /// in …" though none had.
    #[test]
    fn regression_a_failed_run_says_what_it_kept_when_no_law_finished() {
        let dir = Path::new("runs/x");
        let logs = ["tdc.controller.log".to_string(), "tdc.plant.log".into()];
        assert_eq!(
            kept_note(&[], dir, &logs),
            "no law finished: runs/x holds the resolved config.toml, the children's logs (tdc.controller.log, tdc.plant.log), and a summary and report without results"
        );
        assert_eq!(
            kept_note(&[], dir, &[]),
            "no law finished: runs/x holds the resolved config.toml, and a summary and report without results"
        );
        assert_eq!(
            kept_note(&[Law::Tdc, Law::Pid], dir, &logs),
            "the laws that finished (tdc, pid) are kept in runs/x"
        );
    }

    /// `config.toml` is written once, before the runs, and is the resolved config.
    #[test]
    fn run_folder_holds_the_resolved_config() {
        let cfg = RunConfig::from_toml_str(
            "name = \"cfg-once\"\n[scenario]\npath = \"s1\"\n[controller]\nlaws = [\"tdc\"]\n",
            None,
        )
        .unwrap();
        let expected = cfg.to_toml_string();
        let dir = std::env::temp_dir().join(format!("deltaloop-run-cfg-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let o = run(RunRequest {
            out: Some(dir.clone()),
            ..RunRequest::new(cfg, LoopMode::Inproc, "test")
        });
        let written = std::fs::read_to_string(dir.join("config.toml"));
        let others: Vec<bool> = ["trace.csv", "summary.json", "report.md"]
            .iter()
            .map(|f| dir.join(f).is_file())
            .collect();
        let _ = std::fs::remove_dir_all(&dir);
        o.unwrap();
        assert_eq!(written.unwrap(), expected);
        assert_eq!(others, [true; 3]);
    }
}
