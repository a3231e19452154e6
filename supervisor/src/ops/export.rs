//! `deltaloop export RUN_DIR --mcap`: a finished run as one MCAP file ([`deltaloop_report::mcap`]).

pub use deltaloop_report::mcap::{ExportRequest, Exported, export};
