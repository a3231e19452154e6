//! deltaloop in a ROS 2 graph, without ROS: ROS 2's default middleware is DDS, whose wire (RTPS)
//! and type mapping are public, so a pure-Rust DDS (RustDDS) speaks it.
//!
//! - [`live`]: a run's live topics (`run --ros2`), published from what the run records;
//! - [`bench`](mod@bench): the DDS side of `bench ros2`'s ping-pong;
//! - [`node`]: the participant, ROS names, QoS and the node graph (`ros_discovery_info`), and
//!   what the robot of `--controller ros2` is called and waits for (its process is the
//!   controller-side crate `deltaloop-ros2-robot`, on this crate);
//! - [`msg`]: the ROS 2 messages as DDS types.
//!
//! Discovery stays on this host unless the config or ROS 2's environment widens it
//! ([`node::Settings::resolve`]): DDS without DDS-Security authenticates no one.

pub mod bench;
pub mod live;
pub mod msg;
pub mod node;
