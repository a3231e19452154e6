//! `deltaloop bench loop | plant`: the transport's cost and the plant's speed.

use super::Context;
use crate::ops::bench::parse_positive_seconds;
use anyhow::Result;
use clap::Subcommand;
use std::path::PathBuf;

#[derive(clap::Args, Debug)]
pub struct Args {
    #[command(subcommand)]
    what: What,
}

#[derive(Subcommand, Debug)]
enum What {
    /// Transport cost: lockstep over iceoryx2 vs a Unix socket pair vs in-process, and a realtime run.
    Loop {
        /// Simulated seconds of the lockstep and inproc loops.
        #[arg(long, default_value_t = 20.0, value_parser = parse_positive_seconds)]
        lockstep_seconds: f64,
        /// Wall seconds of each realtime run at 3.3 kHz.
        #[arg(long, default_value_t = 60.0, value_parser = parse_positive_seconds)]
        rt_seconds: f64,
        /// Interleaved rounds of the transport-alone measurements (the median is reported).
        #[arg(long, default_value_t = 5, value_parser = clap::value_parser!(u32).range(1..=100))]
        repeats: u32,
        /// Where the configs, logs and histograms go.
        #[arg(long, default_value = "runs/bench-loop")]
        out: PathBuf,
    },
    /// Wall seconds per simulated second: the plant alone (RK4, h = Ts/10), the in-process loop and MuJoCo on the same model.
    Plant {
        /// Simulated seconds per measurement.
        #[arg(long, default_value_t = 2.0, value_parser = parse_positive_seconds)]
        seconds: f64,
        /// Measurements (the median is reported).
        #[arg(long, default_value_t = 5, value_parser = clap::value_parser!(u32).range(1..=1000))]
        repeats: u32,
        /// Python with the pinned `mujoco` that times MuJoCo on the same model, motion and step
        /// (examples/mujoco-plant/bench.py); default: target/python-venv/bin/python if it exists,
        /// else MuJoCo is skipped.
        #[arg(long, value_name = "PYTHON")]
        mujoco: Option<PathBuf>,
    },
}

pub fn exec(a: Args, _cx: &Context) -> Result<()> {
    match a.what {
        What::Plant {
            seconds,
            repeats,
            mujoco,
        } => crate::ops::bench::plant(seconds, repeats, crate::ops::bench::Mujoco::find(mujoco)?),
        What::Loop {
            lockstep_seconds,
            rt_seconds,
            repeats,
            out,
        } => crate::ops::bench_loop::run(lockstep_seconds, rt_seconds, repeats, &out),
    }
}
