//! The scenario configuration (TOML): schema, presets and validation, with errors that name the
//! key, the value and what is allowed. No transport and no physics: the processes and the
//! supervisor read a [`RunConfig`]; the law's constants come from `deltaloop-law`.

pub mod config;
pub mod files;

pub use config::{ConfigError, LoopMode, RecordSection, RunConfig};
pub use deltaloop_law::{ControllerParams, Law, Preset, VelocitySource};
