//! `[faults]`: how the loop reacts to a misbehaving peer, and fault injection; the keys and
//! their checks.

use crate::error::ConfigError;
use crate::keys::{FAULTS, FaultKeys};
use serde::{Deserialize, Serialize};

/// What the drives do with a command beyond ±τ_max (non-finite commands are always rejected).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "kebab-case")]
pub enum TorqueLimit {
    /// Clamp each joint to ±τ_max (counted).
    #[default]
    Clamp,

    /// Reject the whole command and hold the last applied torque (counted).
    Reject,
}

/// A controller fault to inject, for drills and tests: `none`, or `<kind>@<tick>` with kind
/// `nan-torque` (send NaN), `panic` (the process panics), `stall` (stop answering).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum FaultInjection {
    #[default]
    None,
    NanTorque(u64),
    Panic(u64),
    Stall(u64),
}

impl FaultInjection {
    fn parse(s: &str) -> Result<Self, String> {
        if s == "none" {
            return Ok(Self::None);
        }
        let bad =
            || format!("`{s}`: expected none, nan-torque@<tick>, panic@<tick> or stall@<tick>");
        let (kind, tick) = s.split_once('@').ok_or_else(bad)?;
        let tick: u64 = tick.parse().map_err(|_| bad())?;
        match kind {
            "nan-torque" => Ok(Self::NanTorque(tick)),
            "panic" => Ok(Self::Panic(tick)),
            "stall" => Ok(Self::Stall(tick)),
            _ => Err(bad()),
        }
    }
}

impl std::fmt::Display for FaultInjection {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::None => f.write_str("none"),
            Self::NanTorque(k) => write!(f, "nan-torque@{k}"),
            Self::Panic(k) => write!(f, "panic@{k}"),
            Self::Stall(k) => write!(f, "stall@{k}"),
        }
    }
}

impl Serialize for FaultInjection {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(&self.to_string())
    }
}

impl<'de> Deserialize<'de> for FaultInjection {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let s = String::deserialize(d)?;
        Self::parse(&s).map_err(serde::de::Error::custom)
    }
}

/// `[faults]`: how the loop reacts to a misbehaving peer, and fault injection.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FaultSection {
    /// Realtime: this many consecutive missing torques declare the controller dead. The plant holds
    /// the last applied torque through them (the hold window), then stops safely.
    #[serde(default = "FaultKeys::controller_silence_ticks")]
    pub controller_silence_ticks: u32,

    /// Safe stop after a fault: the drives brake with τ = G(q) − D q̇ for this long, then the plant exits, ms.
    #[serde(default = "FaultKeys::safe_stop_ms")]
    pub safe_stop_ms: u32,

    /// Brake damping D of the safe stop, N m s/rad.
    #[serde(default = "FaultKeys::brake_damping_nm_s")]
    pub brake_damping_nm_s: f64,

    /// Commands beyond ±τ_max: `clamp` or `reject`.
    #[serde(default = "FaultKeys::torque_limit")]
    pub torque_limit: TorqueLimit,

    /// Controller fault injection (see [`FaultInjection`]).
    #[serde(default = "FaultKeys::inject")]
    pub inject: FaultInjection,
}

impl Default for FaultSection {
    fn default() -> Self {
        Self {
            controller_silence_ticks: FaultKeys::controller_silence_ticks(),
            safe_stop_ms: FaultKeys::safe_stop_ms(),
            brake_damping_nm_s: FaultKeys::brake_damping_nm_s(),
            torque_limit: FaultKeys::torque_limit(),
            inject: FaultKeys::inject(),
        }
    }
}

impl FaultSection {
    /// `[faults]`: silence window, safe stop, brake.
    pub(crate) fn validate(&self) -> Result<(), ConfigError> {
        FAULTS
            .controller_silence_ticks
            .check_int(self.controller_silence_ticks.into())?;
        FAULTS.safe_stop_ms.check_int(self.safe_stop_ms.into())?;
        FAULTS.brake_damping_nm_s.check(self.brake_damping_nm_s)
    }
}
