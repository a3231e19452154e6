//! What the deltaloop processes agree on: the scenario configuration schema with its validation
//! ([`config`]), the wire types ([`wire`]), the iceoryx2 services of a run ([`ipc`]), and the
//! real-time helpers both loop processes use ([`rt`]).

pub mod config;
pub mod ipc;
pub mod rt;
pub mod wire;

pub use config::{ConfigError, ControllerParams, Law, Preset, RunConfig};
