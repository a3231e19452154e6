//! The `deltaloop` command: its command line ([`cmd`], one file per subcommand) and the
//! operations that are the commands' alone ([`ops`]: benchmarks, export, soak, the live view).
//! What they stand on are crates, each on those below it (tests/e2e/crate_graph.rs), named here
//! by their own names: the pure study ([`deltaloop_study`], with its recorder and metrics in
//! [`deltaloop_study::record`]), loop timing ([`deltaloop_timing`]), the run folder and its files
//! ([`deltaloop_report`]), running ([`deltaloop_runner`], whose runs the commands reach as
//! [`ops::run`], [`ops::join`], [`ops::replay`]), and the studies ([`ops::paper`],
//! [`ops::sweep`]).

pub mod cmd;
pub mod ops;
