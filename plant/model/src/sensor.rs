//! Measurement realism: seeded Gaussian noise on q and q̇, then encoder quantisation of q. The
//! stream is ChaCha8 from a seed, so the same seed gives the same run on every machine. The
//! ground truth stays untouched for evaluation.

use crate::Vec3;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

/// The sensor settings, SI.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SensorConfig {
    /// Encoder counts per joint revolution (0: no quantisation).
    pub encoder_counts_per_rev: u32,
    /// Noise standard deviation on q, rad.
    pub q_noise_std: f64,
    /// Noise standard deviation on q̇, rad/s.
    pub qd_noise_std: f64,
    pub seed: u64,
}

/// A seeded sensor. Allocation-free per sample.
#[derive(Clone, Debug)]
pub struct Sensor {
    cfg: SensorConfig,
    rng: ChaCha8Rng,
    step: f64,
}

impl Sensor {
    pub fn new(cfg: SensorConfig) -> Self {
        let step = if cfg.encoder_counts_per_rev > 0 {
            std::f64::consts::TAU / f64::from(cfg.encoder_counts_per_rev)
        } else {
            0.0
        };
        Self {
            cfg,
            rng: ChaCha8Rng::seed_from_u64(cfg.seed),
            step,
        }
    }

    fn noise(&mut self, std: f64) -> Vec3 {
        match Normal::new(0.0, std) {
            Ok(n) if std > 0.0 => Vec3::new(
                n.sample(&mut self.rng),
                n.sample(&mut self.rng),
                n.sample(&mut self.rng),
            ),
            _ => Vec3::zeros(),
        }
    }

    /// Measures true joint angles q (rad) and rates q̇ (rad/s): noise first, then q is rounded
    /// to the nearest encoder count.
    pub fn measure(&mut self, q: &Vec3, qd: &Vec3) -> (Vec3, Vec3) {
        let mut qm = q + self.noise(self.cfg.q_noise_std);
        let qdm = qd + self.noise(self.cfg.qd_noise_std);
        if self.step > 0.0 {
            qm = qm.map(|x| (x / self.step).round() * self.step);
        }
        (qm, qdm)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cfg(seed: u64) -> SensorConfig {
        SensorConfig {
            encoder_counts_per_rev: 1 << 16,
            q_noise_std: 1e-4,
            qd_noise_std: 1e-2,
            seed,
        }
    }

    #[test]
    fn same_seed_same_stream_other_seed_other_stream() {
        let (q, qd) = (Vec3::new(0.1, 0.2, 0.3), Vec3::new(1.0, -1.0, 0.5));
        let run = |seed| {
            let mut s = Sensor::new(cfg(seed));
            (0..100).map(|_| s.measure(&q, &qd)).collect::<Vec<_>>()
        };
        assert_eq!(run(7), run(7));
        assert_ne!(run(7), run(8));
    }

    #[test]
    fn quantises_to_counts_and_noise_has_its_std() {
        let step = std::f64::consts::TAU / 65536.0;
        let mut s = Sensor::new(cfg(3));
        let (q, qd) = (Vec3::new(0.1, 0.2, 0.3), Vec3::zeros());
        let mut sq = 0.0;
        for _ in 0..20_000 {
            let (qm, qdm) = s.measure(&q, &qd);
            for i in 0..3 {
                let counts = qm[i] / step;
                assert!((counts - counts.round()).abs() < 1e-6);
            }
            sq += qdm.norm_squared();
        }
        let std = (sq / 60_000.0).sqrt();
        assert!((std - 1e-2).abs() < 3e-4, "{std}");
        // Ideal sensor: identity.
        let mut ideal = Sensor::new(SensorConfig {
            encoder_counts_per_rev: 0,
            q_noise_std: 0.0,
            qd_noise_std: 0.0,
            seed: 1,
        });
        assert_eq!(ideal.measure(&q, &qd), (q, qd));
    }
}
