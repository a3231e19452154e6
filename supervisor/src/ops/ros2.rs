//! `--ros2`: the run's live ROS 2 topics, fed by every law's recorder ([`Tap`]).

use anyhow::Result;
use deltaloop_config::RunConfig;
use deltaloop_runner::lawrun::Tap;

/// The longest the run's end waits for its DDS participant to close, s: the process exits
/// within this of the run's end whatever discovery holds.
#[cfg(feature = "ros2")]
const DDS_CLOSE_S: f64 = 1.5;

/// The tap of `--ros2` (None when not asked): joins the ROS 2 graph of the run's `[ros2]` and
/// says where on stderr, with a warning line if discovery reaches beyond this host. With
/// `--controller ros2` it also says what the robot waits for before tick 0.
#[cfg(feature = "ros2")]
pub fn live_tap(cfg: &RunConfig, asked: bool) -> Result<Option<Tap>> {
    use deltaloop_ros2::live::LiveRun;
    use deltaloop_ros2::node::{DropWithin, Settings};
    use deltaloop_study::record::TickSink;
    // The robot of `--controller ros2` publishes the law's reference topics itself.
    let robot = deltaloop_runner::procs::ros2_robot_answers(cfg);
    if robot {
        let line = deltaloop_ros2::node::robot_waiting_line(&Settings::of_run(cfg)?);
        eprintln!(
            "ROS 2: each law's robot (/{}) is {line}; the example node reads the run folder's config.toml",
            deltaloop_ros2::node::ROBOT_NODE
        );
    }
    if !asked {
        return Ok(None);
    }
    let settings = Settings::of_run(cfg)?;
    if let Some(w) = settings.warning() {
        eprintln!("{w}");
    }
    let leaves = if robot {
        "joint_states"
    } else {
        "{joint_states,reference,trajectory}"
    };
    eprintln!(
        "ROS 2: node /{} on DDS domain {} ({}), topics {}, /tf, /clock, /diagnostics, /rosout",
        deltaloop_ros2::live::NODE,
        settings.domain,
        settings.reach(),
        settings.law_topic("<law>", leaves),
    );
    let ts_ns = cfg.ts_ns();
    let live = LiveRun::open(settings, deltaloop_model::DeltaRobot::default(), ts_ns)?;
    let live = DropWithin::new(live, std::time::Duration::from_secs_f64(DDS_CLOSE_S));
    Ok(Some(Tap(std::sync::Arc::new(move |study, law| {
        let topics = live.get().law(law, (!robot).then_some(&study.reference))?;
        Ok(Box::new(topics) as Box<dyn TickSink + Send>)
    }))))
}

/// Without the `ros2` feature: `--ros2` is refused.
#[cfg(not(feature = "ros2"))]
pub fn live_tap(_cfg: &RunConfig, asked: bool) -> Result<Option<Tap>> {
    if asked {
        anyhow::bail!("--ros2: this deltaloop was built without its `ros2` feature");
    }
    Ok(None)
}
