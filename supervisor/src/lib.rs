//! The deltaloop supervisor: scenarios and references, the loop runners, metrics, reports, and the
//! `deltaloop` CLI. Math modules ([`study::scenario`], [`study::reference`], [`record::metrics`],
//! [`study::analysis`]) do no I/O.

pub mod cmd;
pub mod loops;
pub mod ops;
pub mod output;
pub mod record;
pub mod study;
pub mod timing;
