//! The emulated network of a link: its settings (the loop's datagrams are delayed, jittered
//! and dropped by [`crate::link`]).

/// Emulated network on the sending side of each direction (this kernel has no `netem`): every
/// datagram is delayed by `delay_ns` plus a uniform draw from [0, `jitter_ns`], or lost with
/// probability `loss_ppm`/10⁶, from a seeded generator, so a run's link is reproducible. Order is
/// kept (a datagram never overtakes an earlier one), as on one wire.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Emulation {
    /// One-way delay, ns.
    pub delay_ns: u64,
    /// One-way jitter, ns: uniform in [0, jitter_ns] on top of the delay.
    pub jitter_ns: u64,
    /// Loss, parts per million of datagrams.
    pub loss_ppm: u32,
    /// Seed of the draws (the far side uses seed + 1 for its direction).
    pub seed: u64,
}

impl Emulation {
    /// The emulation of the config's `[link]` (validated there: delay and jitter 0..=1 s, loss
    /// 0..=1).
    pub fn of(link: &deltaloop_config::LinkSection) -> Self {
        Self {
            delay_ns: (link.delay_us * 1000.0).round() as u64,
            jitter_ns: (link.jitter_us * 1000.0).round() as u64,
            loss_ppm: (link.loss * 1e6).round() as u32,
            seed: link.seed,
        }
    }

    pub fn is_off(&self) -> bool {
        self.delay_ns == 0 && self.jitter_ns == 0 && self.loss_ppm == 0
    }
}
