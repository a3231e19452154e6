//! The command line every loop process takes from the supervisor (and any process that takes a
//! built-in one's place): the run id, the resolved config and the loop mode.

use deltaloop_config::LoopMode;
use std::path::PathBuf;

/// `--run-id ID --config FILE --mode lockstep|realtime`.
#[derive(clap::Args, Debug, Clone)]
pub struct LoopArgs {
    /// Run id: scopes every iceoryx2 service of this run.
    #[arg(long)]
    pub run_id: String,
    /// Resolved scenario config.
    #[arg(long)]
    pub config: PathBuf,
    /// The loop to run: lockstep or realtime.
    #[arg(long, value_parser = LoopMode::parse_process)]
    pub mode: LoopMode,
}
