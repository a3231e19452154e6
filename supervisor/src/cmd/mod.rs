//! The `deltaloop` command line.

use crate::ops::bench;
use crate::ops::run;
use clap::{Parser, Subcommand};
use deltaloop_config::LoopMode;
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(Parser, Debug)]
#[command(
    name = "deltaloop",
    version,
    about = "Delta robot + model-free TDC-IS-STA control: runs, timing and delay studies"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Run a scenario config: every law of the config (or those given with --law), one run folder.
    Run {
        /// Scenario file (TOML), e.g. configs/s2-fast.toml.
        config: PathBuf,
        /// Loop transport.
        #[arg(long, value_parser = LoopMode::parse, default_value = "realtime")]
        mode: LoopMode,
        #[command(flatten)]
        overrides: run::Overrides,
        /// Run folder (default: runs/<UTC time>-<scenario name>). Must be new or empty.
        #[arg(long)]
        out: Option<PathBuf>,
        /// Empty and reuse a non-empty --out folder (only one that holds a deltaloop run).
        #[arg(long)]
        force: bool,
    },
    /// Reproduce the paper: S1–S3 × both presets × four laws; tables, figures and report.md.
    Paper {
        /// Loop transport.
        #[arg(long, value_parser = LoopMode::parse, default_value = "inproc")]
        mode: LoopMode,
        /// Output folder (default: runs/<UTC time>-paper). Must be new or empty.
        #[arg(long)]
        out: Option<PathBuf>,
        /// Empty and reuse a non-empty --out folder (only one that holds a deltaloop run).
        #[arg(long)]
        force: bool,
    },
    /// Run a grid of delays × laws × scenarios × presets (see configs/delay-sweep.toml); `plan`,
    /// `run` and `merge` split it over machines.
    Sweep(crate::ops::sweep::cmd::SweepArgs),
    /// Re-run a finished run in-process from its folder (config, replies and arrivals in its
    /// trace) and check that it reproduces `trace.csv` byte for byte.
    Replay {
        /// The run folder.
        run_dir: PathBuf,
        /// Where the replayed trace goes (default: RUN_DIR/replay, reused). Must be new or empty,
        /// and apart from RUN_DIR (neither inside it nor holding it).
        #[arg(long)]
        out: Option<PathBuf>,
        /// Empty and reuse a non-empty --out folder (only one that holds a deltaloop run).
        #[arg(long)]
        force: bool,
        /// Also run the same scenario with ideal timing (no latency, no misses) and say what the
        /// measured latency cost.
        #[arg(long)]
        ideal: bool,
    },
    /// Watch a live lockstep or realtime run: ticks, misses, round-trip and wake-lateness
    /// percentiles, tracking error. It only reads (the run's spare observer slot); q quits.
    Top {
        /// The run id (its iceoryx2 services are deltaloop/RUN_ID/...); default: the only live run.
        run_id: Option<String>,
        /// One key=value line per refresh on stdout instead of the screen (also when stdout is
        /// not a terminal); ends with the run.
        #[arg(long)]
        plain: bool,
        /// Time between refreshes, e.g. 250ms, 1s.
        #[arg(long, default_value = "250ms", value_parser = parse_refresh)]
        interval: std::time::Duration,
    },
    /// Run the loop for a long time: the scenario's motion, then its end point held for the rest
    /// of --duration; a progress line, a summary per minute, every tick on disk (also on Ctrl-C).
    Soak {
        /// Scenario file (TOML), e.g. configs/soak.toml (one law, or choose one with --law).
        config: PathBuf,
        /// How long: 90s, 10m, 2h, 1h30m (up to 24h).
        #[arg(long, value_parser = crate::ops::soak::parse_duration)]
        duration: std::time::Duration,
        /// Loop transport (lockstep: --duration is loop time, run as fast as it goes).
        #[arg(long, value_parser = LoopMode::parse_process, default_value = "realtime")]
        mode: LoopMode,
        #[command(flatten)]
        overrides: run::Overrides,
        /// Run folder (default: runs/<UTC time>-soak-<scenario name>). Must be new or empty.
        #[arg(long)]
        out: Option<PathBuf>,
        /// Empty and reuse a non-empty --out folder (only one that holds a deltaloop run).
        #[arg(long)]
        force: bool,
    },
    /// Benchmarks.
    Bench {
        #[command(subcommand)]
        what: BenchCommand,
    },
    /// Internal: the controller side of `bench loop`'s iceoryx2 baseline.
    #[command(hide = true)]
    IoxController {
        #[arg(long)]
        run_id: String,
        #[arg(long)]
        config: PathBuf,
        #[arg(long)]
        cpu: Option<usize>,
        /// Block on the wake-up event instead of polling.
        #[arg(long)]
        blocking: bool,
    },
    /// Internal: the controller side of `bench loop`'s Unix-socket baseline.
    #[command(hide = true)]
    UdsController {
        #[arg(long)]
        socket: PathBuf,
        #[arg(long)]
        config: PathBuf,
        #[arg(long)]
        cpu: Option<usize>,
    },
}

#[derive(Subcommand, Debug)]
enum BenchCommand {
    /// Transport cost: lockstep over iceoryx2 vs a Unix socket pair vs in-process, and a realtime run.
    Loop {
        /// Simulated seconds of the lockstep and inproc loops.
        #[arg(long, default_value_t = 20.0, value_parser = bench::parse_positive_seconds)]
        lockstep_seconds: f64,
        /// Wall seconds of each realtime run at 3.3 kHz.
        #[arg(long, default_value_t = 60.0, value_parser = bench::parse_positive_seconds)]
        rt_seconds: f64,
        /// Interleaved rounds of the transport-alone measurements (the median is reported).
        #[arg(long, default_value_t = 5, value_parser = clap::value_parser!(u32).range(1..=100))]
        repeats: u32,
        /// Where the configs, logs and histograms go.
        #[arg(long, default_value = "runs/bench-loop")]
        out: PathBuf,
    },
    /// Wall seconds per simulated second: the plant alone (RK4, h = Ts/10) and the in-process loop.
    Plant {
        /// Simulated seconds per measurement.
        #[arg(long, default_value_t = 2.0, value_parser = bench::parse_positive_seconds)]
        seconds: f64,
        /// Measurements (the median is reported).
        #[arg(long, default_value_t = 5, value_parser = clap::value_parser!(u32).range(1..=1000))]
        repeats: u32,
    },
}

/// `top --interval`: 50 ms ..= 60 s.
fn parse_refresh(s: &str) -> Result<std::time::Duration, String> {
    let d = humantime::parse_duration(s.trim())
        .map_err(|e| format!("`{s}` is not a duration ({e}): expected e.g. 250ms or 1s"))?;
    if d < std::time::Duration::from_millis(50) || d > std::time::Duration::from_secs(60) {
        return Err(format!("`{s}` is out of range: 50ms ..= 60s"));
    }
    Ok(d)
}

/// `deltaloop replay`: exit 0 when the trace is reproduced byte for byte, 1 otherwise.
fn replay(
    run_dir: &std::path::Path,
    out: Option<PathBuf>,
    force: bool,
    ideal: bool,
) -> anyhow::Result<()> {
    use crate::ops::replay;
    use crate::output::RunFolder;
    let own = run_dir.join("replay");
    // RUN_DIR/replay is the replay's own folder, reused; any other --out follows `run --out`'s
    // rules, and may not be or hold the run folder (regression: `--out RUN` emptied the run).
    let folder = match out {
        Some(out) if !RunFolder::same(&out, &own) => {
            RunFolder::claim_apart(&out, force, &[(run_dir, "the run folder being replayed")])?
        }
        _ => RunFolder::claim(&own, true)?,
    };
    let (verdict, runs) = replay::replay(run_dir, folder.path())?;
    let line = replay::describe(&verdict, run_dir);
    if ideal {
        let cfg = deltaloop_config::RunConfig::from_file(&run_dir.join("config.toml"))?;
        let study = crate::study::Study::new(cfg)?;
        let measured: Vec<_> = runs.iter().map(|r| &r.metrics).collect();
        let best = replay::ideal_rms(&study, &measured)?;
        for l in replay::latency_cost(&measured, &best) {
            println!("{l}");
        }
    }
    match verdict {
        replay::Verdict::Identical { .. } => {
            println!("{line}");
            Ok(())
        }
        _ => anyhow::bail!("{line}"),
    }
}

/// Entry point of the `deltaloop` binary.
pub fn main() -> ExitCode {
    let cli = Cli::parse();
    crate::loops::signals::install();
    if let Err(e) = crate::loops::signals::die_with_parent_from_env() {
        eprintln!("deltaloop: error: {e}");
        return ExitCode::FAILURE;
    }
    let command_line = std::env::args().collect::<Vec<_>>().join(" ");
    let result = match cli.command {
        Command::Run {
            config,
            mode,
            overrides,
            out,
            force,
        } => run::load_config(&config, &overrides)
            .and_then(|cfg| run::run(cfg, mode, out, force, false, &command_line))
            .map(|o| {
                use std::io::Write;
                // Never panic on a closed terminal or pipe: the run folder is already written.
                for n in &o.notes {
                    let _ = writeln!(std::io::stderr(), "{n}");
                }
                let mut out = std::io::stdout().lock();
                let _ = write!(out, "{}", o.table);
                let _ = writeln!(out, "run folder: {}", o.dir.display());
            }),
        Command::Bench {
            what: BenchCommand::Plant { seconds, repeats },
        } => bench::plant(seconds, repeats),
        Command::Bench {
            what:
                BenchCommand::Loop {
                    lockstep_seconds,
                    rt_seconds,
                    repeats,
                    out,
                },
        } => crate::ops::bench_loop::run(lockstep_seconds, rt_seconds, repeats, &out),
        Command::Paper { mode, out, force } => {
            let out = out.unwrap_or_else(|| crate::output::default_run_dir("paper"));
            crate::ops::paper::run(
                mode,
                &out,
                force,
                &command_line,
                std::io::IsTerminal::is_terminal(&std::io::stderr()),
            )
            .map(|s| print!("{}", crate::ops::paper::terminal(&s, &out)))
        }
        Command::Sweep(args) => crate::ops::sweep::cmd::main(args),
        Command::Replay {
            run_dir,
            out,
            force,
            ideal,
        } => replay(&run_dir, out, force, ideal),
        Command::Top {
            run_id,
            plain,
            interval,
        } => crate::ops::top::run(crate::ops::top::Options {
            run_id,
            plain,
            interval,
        }),
        Command::Soak {
            config,
            duration,
            mode,
            overrides,
            out,
            force,
        } => crate::ops::soak::soak(crate::ops::soak::Request {
            config: &config,
            duration,
            mode,
            overrides: &overrides,
            out,
            force,
            command: &command_line,
            tty: std::io::IsTerminal::is_terminal(&std::io::stderr()),
        }),
        Command::UdsController {
            socket,
            config,
            cpu,
        } => crate::ops::bench_loop::uds_controller(&socket, &config, cpu),
        Command::IoxController {
            run_id,
            config,
            cpu,
            blocking,
        } => crate::ops::bench_loop::iox_controller(
            &run_id,
            &config,
            cpu,
            if blocking {
                crate::ops::bench_loop::Handoff::Blocking
            } else {
                crate::ops::bench_loop::Handoff::Polling
            },
        ),
    };
    // After SIGHUP the terminal may be gone: a failed write to stderr must not panic.
    let say = |line: String| {
        use std::io::Write;
        let _ = writeln!(std::io::stderr(), "{line}");
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) if e.downcast_ref::<run::Interrupted>().is_some() => {
            let by = crate::loops::signals::signal().map_or(String::new(), |s| {
                format!(" (by {})", crate::loops::signals::name(s))
            });
            say(format!("deltaloop: {e}{by}"));
            ExitCode::from(130)
        }
        Err(e) => {
            say(format!("deltaloop: error: {e:#}"));
            ExitCode::FAILURE
        }
    }
}
