//! deltaloop in a ROS 2 graph, without ROS: ROS 2's default middleware is DDS, whose wire (RTPS)
//! and type mapping are public, so a pure-Rust DDS (RustDDS) speaks it.
//!
//! - [`live`]: a run's live topics (`run --ros2`), published from what the run records;
//! - [`robot`]: the robot side of a ROS 2 node as the controller (`--controller ros2`);
//! - [`node`]: the participant, ROS names, QoS and the node graph (`ros_discovery_info`);
//! - [`msg`]: the ROS 2 messages as DDS types.
//!
//! Discovery stays on this host unless the config or ROS 2's environment widens it
//! ([`node::Settings::resolve`]): DDS without DDS-Security authenticates no one.

pub mod bench;
pub mod live;
pub mod msg;
pub mod node;
pub mod robot;
