//! `deltaloop bench loop | plant | net | ros2`: the transport's cost, the plant's speed, the
//! link's, and DDS's.

use super::Context;
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
        /// Name each realtime run's missed ticks' causes from the kernel's scheduling record
        /// (root; docs/guide/misses.md).
        #[arg(long)]
        explain: bool,
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
    /// The link between two hosts, on this machine: two network namespaces joined by a veth pair;
    /// a plain UDP ping-pong, realtime S1 + hold across deltaloop-bridge, and the same run on one
    /// host. Needs root and `ip` (iproute2).
    Net {
        /// Seconds the end point is held after S1's 0.8 s motion, in each run.
        #[arg(long, default_value_t = 9.0, value_parser = parse_positive_seconds)]
        hold_s: f64,
        /// Where the runs' folders and logs go (default: a temporary folder, removed at the end).
        #[arg(long)]
        out: Option<PathBuf>,
        /// A deltaloop-bridge built with `--features zenoh`: adds its Zenoh ping-pong (TCP and UDP
        /// endpoints).
        #[arg(long, value_name = "PATH")]
        zenoh_bridge: Option<PathBuf>,
        /// Also the direct path with the controller on CPU 0 (`join --cpu 0`), blocking and with
        /// both loop processes polling 150 µs (`[loop.realtime] spin_us`), and the relay with
        /// the far, then the near bridge polling (`join --spin-us 150`, `--link-spin-us 150`):
        /// four more rows.
        #[arg(long)]
        polling: bool,
        /// Name each run's missed ticks' causes from the kernel's scheduling record of the
        /// plant's CPU (`link` with its leg when the datagram came late; docs/guide/misses.md).
        #[arg(long)]
        explain: bool,
    },
    /// ROS 2's transport against the loop's: a ping-pong of state-sized messages at 3.3 kHz
    /// over DDS (RustDDS, two participants on loopback), iceoryx2 and UDP on loopback,
    /// interleaved rounds.
    Ros2 {
        /// Round trips per row and round (3.3 kHz: 10000 take 3 s).
        #[arg(long, default_value_t = 10_000, value_parser = clap::value_parser!(u64).range(100..=10_000_000))]
        count: u64,
        /// Interleaved rounds (the rows' histograms pool them).
        #[arg(long, default_value_t = 3, value_parser = clap::value_parser!(u32).range(1..=100))]
        rounds: u32,
        /// The DDS domain of the ping-pong (this host only).
        #[arg(long, default_value_t = 231, value_parser = clap::value_parser!(u16).range(0..=232))]
        domain: u16,
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
            explain,
        } => crate::ops::bench_loop::run(lockstep_seconds, rt_seconds, repeats, &out, explain),
        What::Net {
            hold_s,
            out,
            zenoh_bridge,
            polling,
            explain,
        } => {
            // Not this machine's fault but a missing prerequisite: said in one line, exit 2.
            if let Some(why) = crate::ops::bench_net::missing() {
                eprintln!("deltaloop: error: {why}");
                std::process::exit(2);
            }
            crate::ops::bench_net::run(
                hold_s,
                out.as_deref(),
                zenoh_bridge.as_deref(),
                polling,
                explain,
            )
        }
        What::Ros2 {
            count,
            rounds,
            domain,
        } => crate::ops::bench_ros2::run(count, rounds, domain),
    }
}

/// A positive duration in seconds, at most an hour (`--seconds` and the like).
fn parse_positive_seconds(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(v) if v.is_finite() && v > 0.0 && v <= 3600.0 => Ok(v),
        _ => Err(format!(
            "`{s}` is not a duration: expected seconds, 0 < s <= 3600"
        )),
    }
}
