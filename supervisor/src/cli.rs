//! The `deltaloop` command line.

use crate::bench;
use crate::run::{self, Mode};
use clap::{Parser, Subcommand};
use deltaloop_protocol::Law;
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

fn parse_law(s: &str) -> Result<Law, String> {
    Law::parse(s)
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Run a scenario config: every law of the config (or those given with --law), one run folder.
    Run {
        /// Scenario file (TOML), e.g. configs/s2-fast.toml.
        config: PathBuf,
        /// Loop transport.
        #[arg(long, value_enum, default_value = "realtime")]
        mode: Mode,
        /// Run only this law (repeatable): tdc, tde-is, tdc-is-sta, pid.
        #[arg(long = "law", value_parser = parse_law)]
        laws: Vec<Law>,
        /// Run folder (default: runs/<UTC time>-<scenario name>).
        #[arg(long)]
        out: Option<PathBuf>,
    },
    /// Benchmarks.
    Bench {
        #[command(subcommand)]
        what: BenchCommand,
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
        /// Wall seconds of the realtime run at 3.3 kHz.
        #[arg(long, default_value_t = 60.0, value_parser = bench::parse_positive_seconds)]
        rt_seconds: f64,
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

/// Entry point of the `deltaloop` binary.
pub fn main() -> ExitCode {
    let cli = Cli::parse();
    let command_line = std::env::args().collect::<Vec<_>>().join(" ");
    let result = match cli.command {
        Command::Run {
            config,
            mode,
            laws,
            out,
        } => run::load_config(&config, &laws)
            .and_then(|cfg| run::run(cfg, mode, out, &command_line))
            .map(|o| {
                for n in &o.notes {
                    eprintln!("{n}");
                }
                print!("{}", o.table);
                println!("run folder: {}", o.dir.display());
            }),
        Command::Bench {
            what: BenchCommand::Plant { seconds, repeats },
        } => bench::plant(seconds, repeats),
        Command::Bench {
            what:
                BenchCommand::Loop {
                    lockstep_seconds,
                    rt_seconds,
                    out,
                },
        } => crate::bench_loop::run(lockstep_seconds, rt_seconds, &out),
        Command::UdsController {
            socket,
            config,
            cpu,
        } => crate::bench_loop::uds_controller(&socket, &config, cpu),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("deltaloop: error: {e:#}");
            ExitCode::FAILURE
        }
    }
}
