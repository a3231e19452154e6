//! `[link]`: one process of the run on another host, its keys and their checks, and the
//! emulated network ([`LinkEmulation`]) that the section and the `--link-*` flags share.

use crate::error::ConfigError;
use crate::key::range;
use crate::keys::{LINK, LinkKeys};
use crate::text::{show_num, show_str};
use serde::{Deserialize, Serialize};

/// `[link]`: one process of the run on another host, across `deltaloop-bridge`
/// (docs/guide/two-hosts.md). `deltaloop run --controller-remote/--plant-remote` and a sweep's
/// `link_delay_us` axis write it into the run's config; the near bridge, the report and the
/// supervisor read it from there. The emulated delay, jitter and loss act on each datagram, each
/// direction.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LinkSection {
    /// Which process runs on the other host.
    pub remote: RemoteSide,
    /// Where this host listens for the far side (TCP and UDP, one port): `IP:PORT`.
    pub listen: String,
    /// Emulated one-way delay, µs.
    #[serde(default = "LinkKeys::delay_us")]
    pub delay_us: f64,
    /// Emulated one-way jitter, µs: uniform in [0, this] on top of the delay.
    #[serde(default = "LinkKeys::jitter_us")]
    pub jitter_us: f64,
    /// Emulated loss: the fraction of datagrams dropped, 0..=1.
    #[serde(default = "LinkKeys::loss")]
    pub loss: f64,
    /// Seed of the emulated jitter and loss (the far side draws with seed + 1).
    #[serde(default = "LinkKeys::seed")]
    pub seed: u64,
    /// How long the near bridge polls for a reply after sending a state before it blocks, µs
    /// (the relay path's).
    #[serde(default = "LinkKeys::spin_us")]
    pub spin_us: u32,
    /// How the loop's messages cross: `direct` (plant and controller socket to socket, each
    /// bridge handing its socket to the loop process beside it) or `relay` (through both
    /// bridges, as a process that speaks only iceoryx2 always is).
    #[serde(
        default = "LinkKeys::path",
        skip_serializing_if = "LinkPath::is_direct"
    )]
    pub path: LinkPath,
}

deltaloop_names::text_enum! {
    "lowercase", "link path";
    /// How the loop's messages cross the link (`[link] path`, `--link-path`).
    #[derive(Default)]
    pub enum LinkPath {
        /// Socket to socket between the loop processes (a process that cannot take the socket is
        /// relayed by its bridge).
        #[default]
        Direct,
        /// Through both bridges.
        Relay,
    }
}

impl LinkPath {
    pub fn is_direct(&self) -> bool {
        *self == LinkPath::Direct
    }
}

deltaloop_names::text_enum! {
    "lowercase", "remote side";
    /// The process of a run that is on the other host: `[link] remote`, `join --role`, the
    /// `--controller-remote`/`--plant-remote` flags, and the side a bridge stands in for.
    pub enum RemoteSide {
        /// The controller there; the plant and the supervisor here.
        Controller,
        /// The plant there; the controller and the supervisor here.
        Plant,
    }
}

/// The emulated network of a link, each direction on each side's sends (this kernel has no
/// `netem`): `[link]`'s `delay_us`, `jitter_us`, `loss` and `seed`, and `run`'s `--link-*` flags.
/// Checked by [`LinkEmulation::check`], the one place of its bounds.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LinkEmulation {
    /// One-way delay, µs.
    pub delay_us: f64,
    /// One-way jitter, µs: uniform in [0, this] on top of the delay.
    pub jitter_us: f64,
    /// The fraction of datagrams dropped, 0..=1.
    pub loss: f64,
    /// Seed of the jitter and loss draws (the far side draws with seed + 1).
    pub seed: u64,
}

impl Default for LinkEmulation {
    fn default() -> Self {
        Self {
            delay_us: LinkKeys::delay_us(),
            jitter_us: LinkKeys::jitter_us(),
            loss: LinkKeys::loss(),
            seed: LinkKeys::seed(),
        }
    }
}

impl LinkEmulation {
    /// Whether it emulates nothing (no delay, jitter or loss).
    pub fn is_off(&self) -> bool {
        self.delay_us == 0.0 && self.jitter_us == 0.0 && self.loss == 0.0
    }

    /// The bounds of an emulation, wherever it comes from: those of the keys `link.delay_us`,
    /// `link.jitter_us` (0..=[`crate::MAX_LINK_DELAY_US`] µs) and `link.loss` (a fraction).
    pub fn check(&self) -> Result<(), EmulationOutOfRange> {
        for (key, value) in [
            (LINK.delay_us, self.delay_us),
            (LINK.jitter_us, self.jitter_us),
            (LINK.loss, self.loss),
        ] {
            if key.check(value).is_err() {
                return Err(EmulationOutOfRange {
                    field: key.field,
                    value,
                    allowed: key.allowed_text(),
                });
            }
        }
        Ok(())
    }
}

/// A field of a [`LinkEmulation`] outside its range: the field (`delay_us`, `jitter_us` or
/// `loss`), its value and what is allowed. The config names it `link.<field>`, the command line
/// `--link-<field>` ([`Self::flag`]).
#[derive(Clone, Debug, PartialEq)]
pub struct EmulationOutOfRange {
    pub field: &'static str,
    pub value: f64,
    pub allowed: String,
}

impl EmulationOutOfRange {
    /// The flag that sets the field: `--link-delay-us`, `--link-jitter-us`, `--link-loss`.
    pub fn flag(&self) -> String {
        format!("--link-{}", self.field.replace('_', "-"))
    }
}

impl std::fmt::Display for EmulationOutOfRange {
    /// As a command-line error: `--link-loss 2: allowed 0 <= loss <= 1 (…)`.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{} {}: allowed {}",
            self.flag(),
            show_num(self.value),
            self.allowed
        )
    }
}

impl LinkSection {
    /// Whether any emulation (delay, jitter or loss) is on.
    pub fn emulated(&self) -> bool {
        !self.emulation().is_off()
    }

    /// Its emulated network.
    pub fn emulation(&self) -> LinkEmulation {
        LinkEmulation {
            delay_us: self.delay_us,
            jitter_us: self.jitter_us,
            loss: self.loss,
            seed: self.seed,
        }
    }

    /// `[link]`: the address this host listens on, the emulation's and the spin's bounds (in
    /// realtime the spin is bounded by the torque budget too, where the mode is known).
    pub(crate) fn validate(&self) -> Result<(), ConfigError> {
        if self.listen.parse::<std::net::SocketAddr>().is_err() {
            return Err(range(
                &LINK.listen.name(),
                show_str(&self.listen),
                &LINK.listen.allowed_text(),
            ));
        }
        self.emulation()
            .check()
            .map_err(|e| range(&format!("link.{}", e.field), show_num(e.value), &e.allowed))?;
        LINK.spin_us.check_int(self.spin_us.into())
    }
}
