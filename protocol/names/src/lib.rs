//! The words deltaloop's files, command line and processes share: which law runs ([`Law`]), its
//! constants ([`ControllerParams`]) and their presets ([`Preset`]), where the rates come from
//! ([`VelocitySource`]), and the one rule by which every text enum (laws, modes, paths,
//! statuses) gets its word, its parser and its "allowed: …" list ([`text_enum!`]). Plain data:
//! the config schema and the laws both stand on it, and neither on the other.

mod params;
mod text;

pub use params::{
    Compensation, ControllerParams, DelaySource, Law, LawVariant, Preset, VelocitySource,
};
pub use text::{TextEnum, allowed, one_of, parse};
