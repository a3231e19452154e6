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
    /// The emulation of the config's `[link]` (checked there, by `LinkEmulation::check`), in
    /// the units the sender draws in.
    pub fn of(link: &deltaloop_config::LinkSection) -> Self {
        let e = link.emulation();
        Self {
            delay_ns: (e.delay_us * 1000.0).round() as u64,
            jitter_ns: (e.jitter_us * 1000.0).round() as u64,
            loss_ppm: (e.loss * 1e6).round() as u32,
            seed: e.seed,
        }
    }

    pub fn is_off(&self) -> bool {
        self.delay_ns == 0 && self.jitter_ns == 0 && self.loss_ppm == 0
    }
}
