//! `deltaloop export RUN_DIR --mcap`: a finished run as one MCAP file ([`crate::output::mcap`]).

pub use crate::output::mcap::{ExportRequest, Exported, export};
