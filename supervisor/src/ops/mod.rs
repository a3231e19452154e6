//! What the commands do: a run and its folder, the paper, a sweep, a soak, a replay, the
//! benchmarks and the live view. Each is called by its command in `cmd/`.

pub mod bench;
pub mod bench_loop;
pub mod bench_net;
pub mod export;
pub mod join;
pub mod loopback;
pub mod paper;
pub mod replay;
pub mod run;
pub mod soak;
pub mod sweep;
pub mod top;
