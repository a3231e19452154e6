//! The process modes: one `deltaloop-plant` + `deltaloop-controller` pair per law, over iceoryx2.
//!
//! [`run_law`] goes through four phases: spawn the pair (found next to the supervisor's own
//! executable), the handshake (READY from both, the first chunks of the joint reference to the
//! controller, ARMED, START), observe (drain large queues every millisecond, send the reference
//! ahead of the loop; never notify or wait on the loop) until both children exit, and classify
//! how they ended. While it observes, every finished tick goes through the same
//! [`Recorder`](deltaloop_study::record::Recorder) the in-process loop fills (so every row and metric comes
//! from the same code) and on to disk: memory does not grow with the run.

mod children;
mod explain;
mod observe;
mod status;

use crate::feed::ReferenceFeed;
use crate::lawrun::{Keep, LawRun};
use anyhow::{Context, Result, bail};
use children::{Observer, Pair};
use deltaloop_config::{Law, LoopMode};
use deltaloop_config::{Priority, ResolvedLayout};
use deltaloop_study::Study;
use deltaloop_study::record::Fault;
use deltaloop_timing::{Seen, Timing};
use deltaloop_transport::rt;
use deltaloop_transport::wire::Sender;
use std::ops::ControlFlow;
use std::path::{Path, PathBuf};

/// What one law's process run produced.
pub struct ProcessRun {
    /// A loop fault (a child died, stalled, or the plant stopped).
    pub fault: Option<Fault>,
    /// Ctrl-C / SIGTERM stopped the run.
    pub interrupted: bool,
    /// The run id that scoped this pair's iceoryx2 services and nodes.
    pub run_id: String,
    pub run: LawRun,
    pub timing: Timing,
    /// Warnings and errors the children printed (one line each).
    pub child_messages: Vec<String>,
    /// What the controller called itself in its READY, if anything.
    pub controller_label: Option<String>,
}

/// How messages name a process.
fn role(who: Sender) -> &'static str {
    match who {
        Sender::Plant => "plant",
        Sender::Controller => "controller",
        Sender::Supervisor => "supervisor",
    }
}

/// The executable of `--controller ros2`, beside `deltaloop`.
pub const ROS2_ROBOT: &str = "deltaloop-ros2-robot";

/// Whether `cfg`'s controller is the robot of `--controller ros2`, which stands for a ROS 2
/// node: its replies carry τ only, and it publishes the law's reference topics itself.
pub fn ros2_robot_answers(cfg: &deltaloop_config::RunConfig) -> bool {
    cfg.controller
        .command
        .first()
        .is_some_and(|c| Path::new(c).file_name() == Some(std::ffi::OsStr::new(ROS2_ROBOT)))
}

/// Where the child executables are: next to the running one.
pub fn exe_dir() -> Result<PathBuf> {
    let exe = std::env::current_exe().context("cannot locate the deltaloop executable")?;
    Ok(exe.parent().map(Path::to_path_buf).unwrap_or_default())
}

pub use deltaloop_transport::ipc::new_run_id;

/// A callback on the supervisor's finished ticks: `deltaloop soak` watches its own run through it
/// (progress and per-minute summaries) without a second observer on the loop, so the run's spare
/// observer slot stays free for `deltaloop top`. It is called for every tick the observer
/// finishes, in tick order, right after the tick went to the run's timing histograms.
pub type OnTick<'a> = &'a mut dyn FnMut(&Seen);

/// Runs `law` over the study with a real process pair. `run_dir` holds the resolved config the
/// children read and receives their stderr logs and `<law>.timing.csv`; `keep` says where the
/// trace goes; `on_tick` sees every finished tick.
pub fn run_law(
    study: &Study,
    law: Law,
    mode: LoopMode,
    run_dir: &Path,
    keep: &Keep,
    on_tick: Option<OnTick<'_>>,
) -> Result<ProcessRun> {
    let cfg = &study.config;
    let Some(layout) = mode.layout(cfg) else {
        bail!("mode {mode} runs no processes");
    };
    let started = match children::start_pair(study, law, mode, run_dir, keep)? {
        ControlFlow::Continue(started) => started,
        // Ctrl-C (or SIGTERM, SIGHUP) during the handshake: nothing was started.
        ControlFlow::Break(stopped) => return Ok(stopped),
    };
    let sched_warnings = schedule_supervisor(&layout, mode, cfg.loop_.ts_s);
    observe::run(
        started,
        study,
        (law, mode),
        run_dir,
        keep,
        on_tick,
        sched_warnings,
    )
}

/// A pair through the handshake (ARMED from both children; START not sent yet): the run id
/// that scopes its services, the supervisor's ports, the reference feed and the children.
struct Started {
    rid: String,
    obs: Observer,
    feed: ReferenceFeed,
    pair: Pair,
}

/// Pins the supervisor as the layout says; returns the warnings (and, for realtime, those about
/// loop processes polling past the kernel's real-time limit).
fn schedule_supervisor(layout: &ResolvedLayout, mode: LoopMode, ts_s: f64) -> Vec<String> {
    let mut warnings = rt::apply(&rt::Sched {
        core: layout.supervisor_cpu,
        priority: Priority::Other,
        lock_memory: false,
    });
    if mode == LoopMode::Realtime {
        warnings.extend(fifo_share_warnings(layout, ts_s, rt::rt_share_limit()));
    }
    warnings
}

/// Warnings for realtime loop processes that poll at SCHED_FIFO for more of each period than the
/// kernel's real-time limit (`limit`, a share of the CPU) allows: the kernel then stops them to
/// run the other tasks waiting on their CPU, and the loop freezes for up to tens of ms (seen: a
/// controller polling from 290 µs before each 300 µs deadline stalled 30 ms and the plant
/// stopped the run). Each process polls at least from its early wake-up to the deadline.
fn fifo_share_warnings(layout: &ResolvedLayout, ts_s: f64, limit: Option<f64>) -> Vec<String> {
    let Some(limit) = limit else {
        return Vec::new();
    };
    let period_us = ts_s * 1e6;
    [
        (
            "plant",
            "wake_early_us",
            layout.plant_priority,
            layout.plant_cpu,
            Some(f64::from(layout.wake_early_us)),
        ),
        (
            "controller",
            "controller_wake_early_us",
            layout.controller_priority,
            layout.controller_cpu,
            // None: the controller blocks on its event and polls nothing early.
            layout.controller_wake_early_us.map(f64::from),
        ),
    ]
    .into_iter()
    .filter_map(|(who, field, prio, cpu, us)| {
        let us = us?;
        let share = us / period_us;
        (prio != Priority::Other && share >= limit).then(|| {
            format!(
                "[loop.realtime] {field} = {us:.0}: the {who} polls at SCHED_FIFO {:.1} % of every {period_us:.0} µs period, above the kernel's real-time limit of {:.1} % (sched_rt_runtime_us); the kernel will stop it for up to tens of ms to run other tasks on CPU {}; keep {field} below {:.0}",
                share * 100.0,
                limit * 100.0,
                cpu.map_or("(unpinned)".into(), |c| c.to_string()),
                limit * period_us
            )
        })
    })
    .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use deltaloop_config::Layout;

    fn split_with(controller_early_us: i32) -> ResolvedLayout {
        Layout {
            controller_wake_early_us: Some(controller_early_us),
            ..Layout::realtime_split_cpus()
        }
        .resolve()
    }

    /// Regression: a controller told to wake 290 µs before each 300 µs deadline polled 97 % of
    /// the time at SCHED_FIFO; 22 s in, the kernel stopped it for 30 ms to run the supervisor on
    /// its CPU, and the plant ended the run for a silent controller. Nothing had warned.
    #[test]
    fn regression_a_fifo_poll_above_the_kernels_real_time_limit_is_named_with_its_field() {
        let w = fifo_share_warnings(&split_with(290), 3e-4, Some(0.95));
        assert_eq!(w.len(), 1, "{w:?}");
        assert!(
            w[0].contains("controller_wake_early_us = 290")
                && w[0].contains("96.7 %")
                && w[0].contains("95.0 %")
                && w[0].contains("CPU 0")
                && w[0].contains("below 285"),
            "{}",
            w[0]
        );
    }

    #[test]
    fn the_shipped_layouts_and_unlimited_or_non_fifo_loops_get_no_warning() {
        for layout in [
            Layout::realtime_default(),
            Layout::realtime_split_cpus(),
            Layout::realtime_one_cpu_yield(),
        ] {
            assert!(fifo_share_warnings(&layout.resolve(), 3e-4, Some(0.95)).is_empty());
        }
        assert!(fifo_share_warnings(&split_with(290), 3e-4, None).is_empty());
        let other = ResolvedLayout {
            controller_priority: Priority::Other,
            ..split_with(290)
        };
        assert!(fifo_share_warnings(&other, 3e-4, Some(0.95)).is_empty());
        // The controller blocking on its event (−1) polls nothing early.
        assert!(fifo_share_warnings(&split_with(-1), 3e-4, Some(0.95)).is_empty());
    }

    #[test]
    fn the_plant_is_checked_too() {
        let layout = ResolvedLayout {
            wake_early_us: 300,
            ..Layout::realtime_default().resolve()
        };
        let w = fifo_share_warnings(&layout, 3e-4, Some(0.95));
        assert_eq!(w.len(), 1, "{w:?}");
        assert!(w[0].contains("wake_early_us = 300") && w[0].contains("the plant"));
    }
}
