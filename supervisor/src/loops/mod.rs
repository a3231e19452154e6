//! The loops: one law's ticks stepped in-process, replayed, or run by the plant and controller
//! processes and observed; the recorder every mode fills; signals and the reference feed.

pub mod feed;
pub mod inproc;
pub mod lawrun;
pub mod peer_text;
pub mod procs;
pub mod signals;
