//! What the commands do: a run and its folder, the paper, a sweep, a soak, a replay, the
//! benchmarks and the live view. Each is called by its command in `cmd/`.

pub use deltaloop_runner::{join, loopback, replay, run};
pub use deltaloop_studies::{paper, sweep};

pub mod bench;
pub mod bench_loop;
pub mod bench_net;
pub mod bench_ros2;
pub mod export;
pub mod ros2;
pub mod soak;
pub mod top;
