//! `[plant]`: the simulated robot, its keys and their checks.

use crate::error::ConfigError;
use crate::keys::{PLANT, PlantKeys};
use crate::validate::check_command;
use serde::{Deserialize, Serialize};

/// `[plant]`: the simulated robot.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PlantSection {
    /// Joint friction d_f = Fv q̇ + Fc tanh(q̇/ε) on (true) or off.
    #[serde(default = "PlantKeys::friction")]
    pub friction: bool,

    /// Drive torque limit per joint, N m.
    #[serde(default = "PlantKeys::tau_max_nm")]
    pub tau_max_nm: f64,

    /// RK4 steps per control period (h = Ts/substeps).
    #[serde(default = "PlantKeys::substeps")]
    pub substeps: u32,

    /// Transport delay in whole ticks d: with `transport_delay_us` = 0 the plant applies τ_k over
    /// [t_{k+d}, t_{k+d+1}). The delay D is d·Ts + `transport_delay_us`.
    #[serde(default = "PlantKeys::transport_delay_samples")]
    pub transport_delay_samples: u32,

    /// Transport delay beyond the whole ticks, µs (any value ≥ 0; converted to integer ns): τ_k
    /// takes effect at t_k + D, cutting the interval it falls in (docs/delta-robot.md §5).
    #[serde(default = "PlantKeys::transport_delay_us")]
    pub transport_delay_us: f64,

    /// Run this executable (program, then arguments) in place of the built-in `deltaloop-plant`;
    /// it gets the same arguments after these (`--run-id`, `--config`, `--mode`) and must speak
    /// the wire contract (docs/protocol.md). Empty: the built-in plant.
    #[serde(default = "PlantKeys::command", skip_serializing_if = "Vec::is_empty")]
    pub command: Vec<String>,

    /// In realtime mode, when a reply takes effect: at its measured arrival (`arrival`: its
    /// publish time minus the tick's deadline, plus D) or at its tick (`tick`: as if the reply
    /// had been instantaneous; plus D). Other modes have no measured arrival.
    #[serde(default = "PlantKeys::apply_torque")]
    pub apply_torque: ApplyTorque,

    /// Payload step (docs/delta-robot.md §4.3): m_pay jumps from 0 to this mass, kg (0: no step).
    #[serde(default = "PlantKeys::payload_step_kg")]
    pub payload_step_kg: f64,

    /// When the payload step happens, s; the first control instant at or after it. Default: T/2.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub payload_step_at_s: Option<f64>,
}

impl Default for PlantSection {
    fn default() -> Self {
        Self {
            friction: PlantKeys::friction(),
            tau_max_nm: PlantKeys::tau_max_nm(),
            substeps: PlantKeys::substeps(),
            transport_delay_samples: PlantKeys::transport_delay_samples(),
            transport_delay_us: PlantKeys::transport_delay_us(),
            apply_torque: PlantKeys::apply_torque(),
            command: PlantKeys::command(),
            payload_step_kg: PlantKeys::payload_step_kg(),
            payload_step_at_s: None,
        }
    }
}

/// When a realtime reply takes effect (`[plant] apply_torque`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "kebab-case")]
pub enum ApplyTorque {
    /// At its measured arrival (plus the configured transport delay).
    #[default]
    Arrival,

    /// At its tick (plus the configured transport delay), whatever the reply really took.
    Tick,
}

impl PlantSection {
    /// `[plant]`: torque limit, integrator steps, transport delay, payload step (the bounds the
    /// period sets on them: `RunConfig::validate_timing`).
    pub(crate) fn validate(&self) -> Result<(), ConfigError> {
        PLANT.tau_max_nm.check(self.tau_max_nm)?;
        PLANT.substeps.check_int(self.substeps.into())?;
        PLANT
            .transport_delay_samples
            .check_int(self.transport_delay_samples.into())?;
        check_command("plant.command", &self.command)?;
        PLANT.transport_delay_us.check(self.transport_delay_us)?;
        PLANT.payload_step_kg.check(self.payload_step_kg)?;
        if let Some(t) = self.payload_step_at_s {
            PLANT.payload_step_at_s.check(t)?;
        }
        Ok(())
    }
}
