//! How a loop process ends, and its exit code. One table for the plant and the controller (and
//! for any process that takes their place):
//!
//! | code | [`ProcessEnd`] | meaning |
//! |---|---|---|
//! | 0 | `Completed` | the run ended normally (final state published / received) |
//! | 2 | — | bad command-line arguments (printed by the argument parser) |
//! | 3 | — (`Err`) | set-up failed: config, iceoryx2 ports, handshake timeout |
//! | 4 | `Fault` | the loop failed during the run (model failed, safe stop, missing reference) |
//! | 5 | `Stopped` | stopped on request: `Stop` from the supervisor, or SIGTERM |
//! | 6 | `PeerSilent` | the other loop process sent nothing for `loop.silence_timeout_ms` |
//!
//! Code 6 is an echo, not a cause: a controller that gives up on a stalled plant says so, and
//! the supervisor names the plant's stall (or overrun) as what ended the run.
//!
//! The process prints one line on stderr for every end but `Completed`.

use std::fmt::Display;
use std::process::ExitCode;

/// Exit code: bad arguments.
pub const EXIT_USAGE: u8 = 2;
/// Exit code: set-up failed.
pub const EXIT_SETUP: u8 = 3;
/// Exit code: fault during the run.
pub const EXIT_FAULT: u8 = 4;
/// Exit code: stopped on request.
pub const EXIT_STOPPED: u8 = 5;
/// Exit code: the peer loop process was silent for the silence timeout.
pub const EXIT_PEER_SILENT: u8 = 6;

/// How a loop process's run ended (set-up failures are the `Err` of its run function).
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum ProcessEnd {
    /// Every tick ran.
    Completed,
    /// Stopped on request (`Stop`, SIGTERM), before or during the run; says which.
    Stopped(String),
    /// The loop failed; one line says at which tick and why.
    Fault(String),
    /// The peer loop process sent nothing for the silence timeout; one line says how long.
    PeerSilent(String),
}

impl ProcessEnd {
    /// The exit code of this end (see the table above).
    pub fn code(&self) -> u8 {
        match self {
            ProcessEnd::Completed => 0,
            ProcessEnd::Stopped(_) => EXIT_STOPPED,
            ProcessEnd::Fault(_) => EXIT_FAULT,
            ProcessEnd::PeerSilent(_) => EXIT_PEER_SILENT,
        }
    }
}

/// Prints the one-line reason for `name`'s end on stderr and returns its exit code.
pub fn exit<E: Display>(name: &str, end: Result<ProcessEnd, E>) -> ExitCode {
    ExitCode::from(code(name, end))
}

/// [`exit`]'s code as a number (for a process whose `main` is not Rust's: the C ABI).
pub fn code<E: Display>(name: &str, end: Result<ProcessEnd, E>) -> u8 {
    match &end {
        Ok(ProcessEnd::Completed) => 0,
        Ok(
            e @ (ProcessEnd::Stopped(why) | ProcessEnd::Fault(why) | ProcessEnd::PeerSilent(why)),
        ) => {
            eprintln!("{name}: {why}");
            e.code()
        }
        Err(e) => {
            eprintln!("{name}: {e:#}");
            EXIT_SETUP
        }
    }
}
