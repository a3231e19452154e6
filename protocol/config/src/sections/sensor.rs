//! `[sensor]`: measurement realism, its keys and their checks.

use crate::error::ConfigError;
use crate::key::range;
use crate::keys::{SENSOR, SensorKeys};
use deltaloop_names::VelocitySource;
use serde::{Deserialize, Serialize};

/// `[sensor]`: measurement realism, off by default. The plant adds seeded Gaussian noise, then
/// quantises q to encoder counts; ground truth stays noise-free for evaluation.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SensorSection {
    /// Encoder counts per revolution on the joint (0: no quantisation).
    #[serde(default = "SensorKeys::encoder_counts_per_rev")]
    pub encoder_counts_per_rev: u32,

    /// Standard deviation of the noise added to q, rad.
    #[serde(default = "SensorKeys::q_noise_std_rad")]
    pub q_noise_std_rad: f64,

    /// Standard deviation of the noise added to q̇, rad/s.
    #[serde(default = "SensorKeys::qd_noise_std_rad_s")]
    pub qd_noise_std_rad_s: f64,

    /// Seed of the noise (same seed, same run).
    #[serde(default = "SensorKeys::seed")]
    pub seed: u64,

    /// Controller velocity source.
    #[serde(default = "SensorKeys::velocity")]
    pub velocity: VelocitySource,
}

impl Default for SensorSection {
    fn default() -> Self {
        Self {
            encoder_counts_per_rev: SensorKeys::encoder_counts_per_rev(),
            q_noise_std_rad: SensorKeys::q_noise_std_rad(),
            qd_noise_std_rad_s: SensorKeys::qd_noise_std_rad_s(),
            seed: SensorKeys::seed(),
            velocity: SensorKeys::velocity(),
        }
    }
}

impl SensorSection {
    /// Whether the plant perturbs measurements at all.
    pub fn is_ideal(&self) -> bool {
        self.encoder_counts_per_rev == 0
            && self.q_noise_std_rad == 0.0
            && self.qd_noise_std_rad_s == 0.0
    }

    /// `[sensor]`: noise levels and encoder resolution.
    pub(crate) fn validate(&self) -> Result<(), ConfigError> {
        SENSOR.q_noise_std_rad.check(self.q_noise_std_rad)?;
        SENSOR.qd_noise_std_rad_s.check(self.qd_noise_std_rad_s)?;
        let counts = self.encoder_counts_per_rev;
        if counts != 0 && counts < 16 {
            return Err(range(
                &SENSOR.encoder_counts_per_rev.name(),
                counts,
                &SENSOR.encoder_counts_per_rev.allowed_text(),
            ));
        }
        Ok(())
    }
}
