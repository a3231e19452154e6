//! The scenario configuration (TOML): schema, presets and validation, with errors that name the
//! key, the value and what is allowed. No transport and no physics: the processes and the
//! supervisor read a [`RunConfig`]; the laws' names and constants come from `deltaloop-names`.
//!
//! A file names a scenario, the plant options, the controller laws and a preset of controller
//! constants (`matched` or `paper`, see docs/controllers.md), and may override any constant key by
//! key. [`RunConfig::from_toml_str`] rejects unknown keys and out-of-range values with an error that
//! names the key, the value and what is allowed. The resolved config ([`RunConfig::to_toml_string`])
//! has every constant filled in and parses back to the same config.
//!
//! | module | holds |
//! |---|---|
//! | [`keys`] | every key declared once: TOML path, type, unit, allowed values, default, doc line; the serde defaults, the range checks, the doc's key table and the fuzzer's keys come from it |
//! | [`key`] | what a declaration holds ([`Key`]), its range check and one-line error, its row of the key table |
//! | [`schema`] | [`RunConfig`], the whole file: reading and writing it; its sections re-exported |
//! | `sections` | one module per section (`[scenario]`, `[plant]`, `[controller]`, `[loop]`, `[sensor]`, `[faults]`, `[record]`, `[link]`, `[ros2]`): its serde struct, defaults and checks |
//! | [`layout`] | the `[loop.<mode>]` layouts: the TOML table, its defaults per mode, its checks, and [`ResolvedLayout`] in real types |
//! | [`mode`] | [`LoopMode`]: inproc, lockstep, realtime |
//! | `validate` | a whole config's checks: each section's, then the keys bounded by the period and the run's length; the limits (`MAX_*`, [`NAME_RULE`]) |
//! | [`text`] | echoing user text in one-line errors |
//! | [`error`] | [`ConfigError`] |
//! | [`files`] | the one way every input file is opened |
//!
//! Everything is re-exported here.

pub mod error;
pub mod files;
pub mod key;
pub mod keys;
pub mod layout;
pub mod limits;
pub mod mode;
pub mod schema;
mod sections;
pub mod text;
mod validate;

pub use deltaloop_names::{
    Compensation, ControllerParams, DelaySource, Law, LawVariant, Preset, VelocitySource,
};
pub use error::ConfigError;
pub use files::{MAX_FILE_BYTES, read_text_file};
pub use key::{Allowed, Bounds, Key, KeyDefault};
pub use layout::{Layout, Poll, Priority, ResolvedLayout};
pub use mode::LoopMode;
pub use schema::{
    ApplyTorque, ControllerSection, EmulationOutOfRange, FaultInjection, FaultSection,
    LinkEmulation, LinkPath, LinkSection, LoopSection, Overrun, PathKind, PlantSection,
    RecordSection, RemoteSide, Ros2Distro, Ros2Range, Ros2Section, RunConfig, ScenarioSection,
    Segment, SensorSection, TorqueLimit,
};
pub use text::{
    MAX_ECHO_CHARS, clean_message, show_num, show_path, show_str, toml_error_line,
    toml_error_position,
};
pub use validate::{
    MAX_HOLD_S, MAX_LINK_DELAY_US, MAX_SUBSTEPS, MAX_TDE_DELAY, MAX_TICKS, MAX_TRANSPORT_DELAY,
    MAX_TRANSPORT_DELAY_US, NAME_RULE, name_is_valid,
};

/// What the unit tests of several modules share.
#[cfg(test)]
mod test_util {
    use crate::RunConfig;
    use std::path::Path;

    /// The smallest valid scenario file.
    pub const MIN: &str = "[scenario]\npath = \"s1\"\n";

    /// The error of `text` (labelled `configs/t.toml`), checked to be one line.
    pub fn err(text: &str) -> String {
        let e = RunConfig::from_toml_str(text, Some(Path::new("configs/t.toml")))
            .unwrap_err()
            .to_string();
        assert!(!e.contains('\n') && !e.contains('\r'), "not one line: {e}");
        e
    }
}
