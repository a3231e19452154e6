//! The deltaloop supervisor: scenarios and references, the loop runners, metrics, reports, and the
//! `deltaloop` CLI. Math modules ([`scenario`], [`reference`], [`metrics`], [`analysis`]) do no I/O.

pub mod analysis;
pub mod bench;
pub mod bench_loop;
pub mod cli;
pub mod feed;
pub mod hlog;
pub mod inproc;
pub mod lawrun;
pub mod live;
pub mod metrics;
pub mod output;
pub mod paper;
pub mod peer_text;
pub mod plot;
pub mod procs;
pub mod record;
pub mod reference;
pub mod replay;
pub mod report;
pub mod run;
pub mod scenario;
pub mod signals;
pub mod soak;
pub mod study;
pub mod sweep;
pub mod tick_hook;
pub mod timeline;
pub mod timing;
pub mod top;
