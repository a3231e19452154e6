//! The `deltaloop` command line: one module per subcommand, each with its argument struct and one
//! `exec(args, &Context)` entry, the way cargo lays out its commands. The work itself is in
//! [`crate::ops`]; nothing outside this folder uses it.

mod bench;
mod export;
mod helpers;
mod join;
mod link_key;
mod overrides;
mod paper;
mod replay;
mod run;
mod soak;
mod sweep;
mod top;
mod whatif;
mod words;

use clap::{Parser, Subcommand};
use deltaloop_study::record::RunStatus;
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
    Run(run::Args),
    /// Reproduce the paper: S1–S3 × both presets × four laws; tables, figures and report.md.
    Paper(paper::Args),
    /// Run a grid of delays × laws × scenarios × presets (see configs/delay-sweep.toml); `plan`,
    /// `run` and `merge` split it over machines.
    Sweep(sweep::Args),
    /// Write a finished run as one MCAP file (Foxglove, PlotJuggler, ros2 bag): joint states,
    /// the control signals, loop timing, events and the robot in 3D, per law.
    Export(export::Args),
    /// Re-run a finished run in-process from its folder (config, replies and arrivals in its
    /// trace) and check that it reproduces `trace.csv` byte for byte.
    Replay(replay::Args),
    /// What a measured latency distribution would cost the tracking: each law run in-process
    /// over many latency sequences drawn from a realtime run, an HdrHistogram or a text file.
    Whatif(whatif::Args),
    /// Watch a live lockstep or realtime run: ticks, misses, round-trip and wake-lateness
    /// percentiles, tracking error. It only reads (the run's spare observer slot); q quits.
    Top(top::Args),
    /// Run the loop for a long time: the scenario's motion, then its end point held for the rest
    /// of --duration; a progress line, a summary per minute, every tick on disk (also on Ctrl-C).
    Soak(soak::Args),
    /// Benchmarks.
    Bench(bench::Args),
    /// Run the controller (`--role controller`) or the plant (`--role plant`) of a run on this
    /// host, the supervisor being on another (`deltaloop run … --controller-remote HOST:PORT` or
    /// `--plant-remote HOST:PORT` there).
    Join(join::Args),
    /// Write a fresh random link key to a new file (mode 600), for `run --link-key` and
    /// `join --link-key`.
    LinkKey(link_key::Args),
    /// Internal: the controller side of `bench loop`'s iceoryx2 baseline.
    #[command(hide = true)]
    IoxController(helpers::IoxArgs),
    /// Internal: the controller side of `bench loop`'s Unix-socket baseline.
    #[command(hide = true)]
    UdsController(helpers::UdsArgs),
}

/// `--out` and `--force`, shared by every command that writes a folder.
#[derive(clap::Args, Debug)]
pub struct OutArgs {
    /// Output folder (default: a new one in runs/, named by the UTC time and what runs). Must be
    /// new or empty.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Empty and reuse a non-empty --out folder (only one that holds a deltaloop run).
    #[arg(long)]
    pub force: bool,
}

/// What every command gets besides its own arguments.
pub struct Context {
    /// The command line, for `summary.json` and `report.md`.
    pub command_line: String,
    /// stderr is a terminal: draw progress bars.
    pub tty: bool,
}

/// Entry point of the `deltaloop` binary.
pub fn main() -> ExitCode {
    let cli = Cli::parse();
    deltaloop_runner::signals::install();
    if let Err(e) = deltaloop_runner::signals::die_with_parent_from_env() {
        eprintln!("deltaloop: error: {e}");
        return ExitCode::from(exit_code(RunStatus::Error));
    }
    let cx = Context {
        command_line: std::env::args().collect::<Vec<_>>().join(" "),
        tty: std::io::IsTerminal::is_terminal(&std::io::stderr()),
    };
    let result = match cli.command {
        Command::Run(a) => run::exec(a, &cx),
        Command::Paper(a) => paper::exec(a, &cx),
        Command::Sweep(a) => sweep::exec(a, &cx),
        Command::Replay(a) => replay::exec(a, &cx),
        Command::Whatif(a) => whatif::exec(a, &cx),
        Command::Export(a) => export::exec(a, &cx),
        Command::Top(a) => top::exec(a, &cx),
        Command::Soak(a) => soak::exec(a, &cx),
        Command::Bench(a) => bench::exec(a, &cx),
        Command::Join(a) => join::exec(a, &cx),
        Command::LinkKey(a) => link_key::exec(a, &cx),
        Command::IoxController(a) => helpers::exec_iox(a, &cx),
        Command::UdsController(a) => helpers::exec_uds(a, &cx),
    };
    // After SIGHUP the terminal may be gone: a failed write to stderr must not panic.
    let say = |line: String| {
        use std::io::Write;
        let _ = writeln!(std::io::stderr(), "{line}");
    };
    let status = match &result {
        Ok(()) => RunStatus::Ok,
        Err(e) => crate::ops::run::error_status(e),
    };
    match (result, status) {
        (Ok(()), _) => {}
        (Err(e), RunStatus::Interrupted) => {
            let by = deltaloop_runner::signals::signal().map_or(String::new(), |s| {
                format!(" (by {})", deltaloop_runner::signals::name(s))
            });
            say(format!("deltaloop: {e}{by}"));
        }
        (Err(e), _) => say(format!("deltaloop: error: {e:#}")),
    }
    ExitCode::from(exit_code(status))
}

/// The exit code of `deltaloop` for how its command ended: 0 for `ok` and `diverged` (a
/// divergence is a result), 130 for `interrupted` (as a shell reports Ctrl-C), 1 for the rest
/// (a fault, a stop on request, lost data, an error).
pub fn exit_code(status: RunStatus) -> u8 {
    match status {
        RunStatus::Ok | RunStatus::Diverged => 0,
        RunStatus::Interrupted => 130,
        RunStatus::Stopped | RunStatus::LostData | RunStatus::Fault | RunStatus::Error => 1,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use strum::VariantArray;

    /// `join --role` takes the two roles only: anything else is a one-line error naming them
    /// (clap's, exit 2).
    #[test]
    fn join_refuses_an_unknown_role_naming_the_allowed_ones() {
        let e = Cli::try_parse_from(["deltaloop", "join", "127.0.0.1:7447", "--role", "observer"])
            .unwrap_err()
            .to_string();
        let first = e.lines().next().unwrap_or_default();
        assert!(
            first.contains("observer") && e.contains("controller") && e.contains("plant"),
            "{e}"
        );
    }

    /// A divergence is a result (0), an interrupt is 130 as in a shell, everything else fails.
    #[test]
    fn every_status_has_its_exit_code() {
        for &s in RunStatus::VARIANTS {
            let want = match s {
                RunStatus::Ok | RunStatus::Diverged => 0,
                RunStatus::Interrupted => 130,
                _ => 1,
            };
            assert_eq!(exit_code(s), want, "{s}");
        }
    }
}
