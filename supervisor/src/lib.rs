//! The `deltaloop` command: its command line ([`cmd`], one file per subcommand) and the
//! operations that are the commands' alone ([`ops`]: benchmarks, export, soak, the live view).
//! What they stand on are crates, each on those below it (tests/e2e/crate_graph.rs), re-exported
//! here under their layer's name: the pure study ([`study`], [`record`]: scenario, reference,
//! recorder, metrics), loop [`timing`], the run folder and its files ([`output`]: the report
//! crate), running ([`loops`]: the runner crate, with [`ops::run`], [`ops::join`],
//! [`ops::replay`]), and the studies ([`ops::paper`], [`ops::sweep`]).

pub mod cmd;
pub use deltaloop_runner as loops;
pub mod ops;
pub use deltaloop_report as output;
pub use deltaloop_study as study;
pub use deltaloop_study::record;
pub use deltaloop_timing as timing;
