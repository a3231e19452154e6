//! What the deltaloop processes agree on: the scenario configuration schema with its validation
//! ([`config`]). Every binary parses configs through this crate, so a file means the same thing to
//! the supervisor, the plant and the controller.

pub mod config;

pub use config::{ConfigError, ControllerParams, Law, Preset, RunConfig};
