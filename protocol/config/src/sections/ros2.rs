//! `[ros2]`: how deltaloop appears in a ROS 2 graph, its keys and their checks.

use crate::error::ConfigError;
use crate::key::range;
use crate::keys::{ROS2, Ros2Keys};
use crate::text::show_str;
use crate::validate::{ROS_NAME_RULE, ros_name_is_valid};
use serde::{Deserialize, Serialize};

/// `[ros2]`: how deltaloop appears in a ROS 2 graph (docs/guide/ros2.md). DDS without
/// DDS-Security authenticates no one, so discovery stays on this host unless asked otherwise.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Ros2Section {
    /// DDS domain, 0..=232 (None: `ROS_DOMAIN_ID`, else 0).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub domain: Option<u16>,
    /// Discovery range (None: `ROS_AUTOMATIC_DISCOVERY_RANGE`, else `localhost`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub range: Option<Ros2Range>,
    /// The live topics' namespace: `/<namespace>/<law>/joint_states`, … (ROS name tokens).
    pub namespace: String,
    /// Publish every this many ticks (1: every tick; 10: 333 Hz at Ts = 0.3 ms).
    pub every: u32,
    /// `--controller ros2`: the robot's joint states, published by deltaloop (a ROS name).
    pub state_topic: String,
    /// `--controller ros2`: the node's commands (JointState, `effort` in N m) (a ROS name).
    pub command_topic: String,
    /// The ROS 2 distribution whose graph format `ros_discovery_info` uses.
    pub distro: Ros2Distro,
    /// `--controller ros2`: how long to wait for the node to appear, s.
    pub wait_s: f64,
}

impl Default for Ros2Section {
    fn default() -> Self {
        Self {
            domain: None,
            range: None,
            namespace: Ros2Keys::namespace(),
            every: Ros2Keys::every(),
            state_topic: Ros2Keys::state_topic(),
            command_topic: Ros2Keys::command_topic(),
            distro: Ros2Keys::distro(),
            wait_s: Ros2Keys::wait_s(),
        }
    }
}

deltaloop_names::text_enum! {
    "lowercase", "ROS 2 discovery range";
    /// How far DDS discovery reaches (`[ros2] range`, ROS 2's `ROS_AUTOMATIC_DISCOVERY_RANGE`).
    pub enum Ros2Range {
        /// This host only (loopback): the default.
        Localhost,
        /// The local networks (multicast): anyone there can read the run and, with
        /// `--controller ros2`, command the robot.
        Subnet,
    }
}

deltaloop_names::text_enum! {
    "lowercase", "ROS 2 distribution";
    /// The graph format of `ros_discovery_info`: Humble's 24-byte gids or Jazzy's 16.
    #[derive(Default)]
    pub enum Ros2Distro {
        Humble,
        #[default]
        Jazzy,
    }
}

impl Ros2Section {
    /// `[ros2]`: the domain, the names, the rate and the wait.
    pub(crate) fn validate(&self) -> Result<(), ConfigError> {
        if let Some(d) = self.domain {
            ROS2.domain.check_int(d.into())?;
        }
        if !ros_name_is_valid(&self.namespace) {
            return Err(range(
                "ros2.namespace",
                show_str(&self.namespace),
                ROS_NAME_RULE,
            ));
        }
        for (key, t) in [
            ("ros2.state_topic", &self.state_topic),
            ("ros2.command_topic", &self.command_topic),
        ] {
            if !ros_name_is_valid(t.strip_prefix('/').unwrap_or(t)) {
                return Err(range(key, show_str(t), ROS_NAME_RULE));
            }
        }
        let topic = |t: &str| t.trim_start_matches('/').to_owned();
        if topic(&self.state_topic) == topic(&self.command_topic) {
            return Err(range(
                "ros2.command_topic",
                show_str(&self.command_topic),
                &format!(
                    "a topic other than ros2.state_topic's ({}): the robot would read its own states as commands",
                    show_str(&self.state_topic)
                ),
            ));
        }
        ROS2.every.check_int(self.every.into())?;
        ROS2.wait_s.check(self.wait_s)
    }
}
