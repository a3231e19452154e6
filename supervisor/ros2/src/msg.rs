//! The ROS 2 messages deltaloop speaks, as DDS sees them: each `pkg/msg/Name` is the DDS type
//! `pkg::msg::dds_::Name_`, a final struct in plain CDR (XCDR1), its fields in the `.msg` file's
//! order (identical in Humble and Jazzy for these types). serde's order is the wire's.

use serde::{Deserialize, Serialize};

/// A ROS 2 message type: its DDS type name.
pub trait RosType {
    /// `pkg::msg::dds_::Name_`.
    const DDS_TYPE: &'static str;
}

macro_rules! ros_type {
    ($t:ty, $name:literal) => {
        impl RosType for $t {
            const DDS_TYPE: &'static str = $name;
        }
    };
}

/// builtin_interfaces/Time (and Duration, the same layout): s and ns.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Time {
    pub sec: i32,
    pub nanosec: u32,
}

impl Time {
    /// `t_ns` (ns since the run's start: the simulated clock k·Ts).
    pub fn of_ns(t_ns: u64) -> Self {
        Self {
            // A run is far shorter than 68 years.
            sec: (t_ns / 1_000_000_000) as i32,
            nanosec: (t_ns % 1_000_000_000) as u32,
        }
    }

    /// Back to ns; None for a negative time.
    pub fn ns(&self) -> Option<u64> {
        u64::try_from(self.sec)
            .ok()
            .map(|s| s * 1_000_000_000 + u64::from(self.nanosec))
    }
}

/// std_msgs/Header.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Header {
    pub stamp: Time,
    pub frame_id: String,
}

/// sensor_msgs/JointState: rad, rad/s, N m per named joint.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct JointState {
    pub header: Header,
    pub name: Vec<String>,
    pub position: Vec<f64>,
    pub velocity: Vec<f64>,
    pub effort: Vec<f64>,
}
ros_type!(JointState, "sensor_msgs::msg::dds_::JointState_");

/// rosgraph_msgs/Clock: the simulated time, for nodes with `use_sim_time`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Clock {
    pub clock: Time,
}
ros_type!(Clock, "rosgraph_msgs::msg::dds_::Clock_");

/// geometry_msgs/Vector3, m.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Vector3 {
    pub x: f64,
    pub y: f64,
    pub z: f64,
}

/// geometry_msgs/Quaternion.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Quaternion {
    pub x: f64,
    pub y: f64,
    pub z: f64,
    pub w: f64,
}

/// geometry_msgs/Transform.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Transform {
    pub translation: Vector3,
    pub rotation: Quaternion,
}

/// geometry_msgs/TransformStamped.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TransformStamped {
    pub header: Header,
    pub child_frame_id: String,
    pub transform: Transform,
}

/// tf2_msgs/TFMessage.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TfMessage {
    pub transforms: Vec<TransformStamped>,
}
ros_type!(TfMessage, "tf2_msgs::msg::dds_::TFMessage_");

/// diagnostic_msgs/KeyValue.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct KeyValue {
    pub key: String,
    pub value: String,
}

/// diagnostic_msgs/DiagnosticStatus (`level`: OK 0, WARN 1, ERROR 2, STALE 3).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct DiagnosticStatus {
    pub level: u8,
    pub name: String,
    pub message: String,
    pub hardware_id: String,
    pub values: Vec<KeyValue>,
}

/// diagnostic_msgs/DiagnosticArray.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct DiagnosticArray {
    pub header: Header,
    pub status: Vec<DiagnosticStatus>,
}
ros_type!(
    DiagnosticArray,
    "diagnostic_msgs::msg::dds_::DiagnosticArray_"
);

/// rcl_interfaces/Log (`level`: DEBUG 10, INFO 20, WARN 30, ERROR 40, FATAL 50).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Log {
    pub stamp: Time,
    pub level: u8,
    pub name: String,
    pub msg: String,
    pub file: String,
    pub function: String,
    pub line: u32,
}
ros_type!(Log, "rcl_interfaces::msg::dds_::Log_");

/// The level of [`Log`]'s lines here (the run's events).
pub const INFO: u8 = 20;

/// trajectory_msgs/JointTrajectoryPoint: rad, rad/s, rad/s², N m; `time_from_start` a Duration.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct JointTrajectoryPoint {
    pub positions: Vec<f64>,
    pub velocities: Vec<f64>,
    pub accelerations: Vec<f64>,
    pub effort: Vec<f64>,
    pub time_from_start: Time,
}

/// trajectory_msgs/JointTrajectory.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct JointTrajectory {
    pub header: Header,
    pub joint_names: Vec<String>,
    pub points: Vec<JointTrajectoryPoint>,
}
ros_type!(
    JointTrajectory,
    "trajectory_msgs::msg::dds_::JointTrajectory_"
);

/// rmw_dds_common/NodeEntitiesInfo; a gid is Jazzy's 16 bytes or Humble's 24 (the GUID, zero
/// padded), each as a `Gid_` struct of one octet array (serialized as its bytes).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct NodeEntitiesInfo<G> {
    pub node_namespace: String,
    pub node_name: String,
    pub reader_gid_seq: Vec<G>,
    pub writer_gid_seq: Vec<G>,
}

/// rmw_dds_common/ParticipantEntitiesInfo: a participant's nodes, on `ros_discovery_info`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ParticipantEntitiesInfo<G> {
    pub gid: G,
    pub node_entities_info_seq: Vec<NodeEntitiesInfo<G>>,
}

/// The DDS type of [`ParticipantEntitiesInfo`].
pub const PARTICIPANT_ENTITIES_INFO: &str = "rmw_dds_common::msg::dds_::ParticipantEntitiesInfo_";

/// Jazzy's (and Iron's) gid: the endpoint's 16-byte GUID.
pub type Gid16 = [u8; 16];
/// Humble's gid: the GUID and 8 zero bytes.
pub type Gid24 = [u8; 24];

/// The names of the Delta's three joints (as in the MCAP export).
pub const JOINTS: [&str; 3] = ["joint_1", "joint_2", "joint_3"];

/// The frame the joint states and the pose are given in.
pub const BASE_FRAME: &str = "base";

/// A JointState of the three joints at `t_ns`: positions (rad), velocities (rad/s), efforts
/// (N m); an empty slice leaves that array empty.
pub fn joint_state(t_ns: u64, position: &[f64], velocity: &[f64], effort: &[f64]) -> JointState {
    JointState {
        header: Header {
            stamp: Time::of_ns(t_ns),
            frame_id: BASE_FRAME.into(),
        },
        name: JOINTS.map(String::from).to_vec(),
        position: position.to_vec(),
        velocity: velocity.to_vec(),
        effort: effort.to_vec(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The JointState RustDDS puts on the wire is the MCAP export's, byte for byte: one encoding
    /// of the message, seen live or read back from a file.
    #[test]
    fn a_joint_state_on_dds_is_the_mcap_files_bytes() {
        let (q, qd, tau) = (
            [1.0 / 3.0, -0.0, 2.5e-7],
            [f64::MIN_POSITIVE, 1.0, -2.0],
            [3.0, 4.0, 5.0],
        );
        let t = 1_500_000_300;
        let m = joint_state(t, &q, &qd, &tau);
        let mut dds = vec![0x00, 0x01, 0x00, 0x00]; // CDR_LE, as RustDDS's adapter writes it
        let le = rustdds::RepresentationIdentifier::CDR_LE;
        rustdds::serialization::to_writer_with_rep_id(&mut dds, &m, le).unwrap();
        assert_eq!(dds, deltaloop_mcap::cdr::joint_state(t, &q, &qd, &tau));
    }

    #[test]
    fn a_time_goes_to_ns_and_back() {
        for t in [0, 299_999_999_700, 1_000_000_000, u64::from(u32::MAX) * 7] {
            assert_eq!(Time::of_ns(t).ns(), Some(t));
        }
        assert_eq!(
            Time {
                sec: -1,
                nanosec: 0
            }
            .ns(),
            None
        );
    }
}
