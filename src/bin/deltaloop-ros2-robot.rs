//! `deltaloop-ros2-robot`: the robot's side of a ROS 2 controller node, started by
//! `deltaloop run --controller ros2` in the controller's place.
fn main() -> std::process::ExitCode {
    deltaloop_ros2_robot::main()
}
