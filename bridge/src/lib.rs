//! deltaloop-bridge: one run's iceoryx2 services carried between two hosts.
//!
//! The loop's messages (state out, torque back) travel as one UDP datagram each, the `#[repr(C)]`
//! wire type byte for byte behind a 16-byte header ([`frame`]); run control, the reference chunks,
//! the final state and the far process's log and exit travel over one TCP connection (reliable
//! and ordered, off the 3.3 kHz path; with a remote plant also its telemetry, its control
//! messages and a copy of every state for the record). On each host the bridge is an ordinary
//! iceoryx2 peer (zero copy there): on the supervisor's host (`near`) it is the remote process,
//! the controller (`--controller-remote`) or the plant (`--plant-remote`); on the other host
//! (`far`) it is the supervisor and the process that runs with the supervisor. Wake-up events are
//! forwarded ([`sides`]): on the plant's host the bridge wakes on `state-ready` and notifies
//! `torque-ready`, on the controller's host the other way round, so each process wakes as it
//! would on one host. `ping`/`pong` measure a plain UDP ping-pong between
//! the same hosts, the baseline of `docs/performance.md`.
//!
//! The per-tick path allocates nothing and takes no lock: `ppoll` on the socket and the event,
//! `recv`/`send` of one datagram, iceoryx2's publish and notify, the clock.

pub mod far;
pub mod files;
pub mod hello;
pub mod link;
pub mod near;
pub mod ping;
pub mod seal;
pub mod sides;
#[cfg(feature = "zenoh")]
pub mod zping;

pub use deltaloop_link::{bytes, direct, emulation, frame, replies};

use anyhow::{Result, bail};
use clap::{Parser, Subcommand};
use std::net::{SocketAddr, ToSocketAddrs};
use std::process::ExitCode;

const NAME: &str = "deltaloop-bridge";

#[derive(Parser, Debug)]
#[command(
    name = "deltaloop-bridge",
    about = "Carries one deltaloop run between two hosts (started by `deltaloop run --controller-remote` or `--plant-remote`, and `deltaloop join`)"
)]
struct Cli {
    #[command(subcommand)]
    side: Side,
}

#[derive(Subcommand, Debug)]
enum Side {
    /// The supervisor's host: stands in for the remote controller or plant (started by the
    /// supervisor).
    Near(near::Args),
    /// The other host: stands in for the supervisor and the process with it, starts the remote
    /// one.
    Far(far::Args),
    /// Plain UDP ping-pong, client side: the baseline round trip.
    Ping(ping::PingArgs),
    /// Plain UDP ping-pong, echo side.
    Pong(ping::PongArgs),
    /// The same ping-pong over Zenoh, client side (feature `zenoh`).
    #[cfg(feature = "zenoh")]
    Zping(zping::ZPingArgs),
    /// The same ping-pong over Zenoh, echo side (feature `zenoh`).
    #[cfg(feature = "zenoh")]
    Zpong(zping::ZPongArgs),
}

/// The emulated network (both directions, on each side's sends; this kernel has no `netem`).
#[derive(clap::Args, Debug, Clone, Default)]
pub struct EmuArgs {
    /// Emulated one-way link delay, µs (each direction; the round trip grows by twice this).
    #[arg(long, default_value_t = 0.0)]
    pub link_delay_us: f64,
    /// Emulated one-way jitter, µs: uniform in [0, this] on top of the delay.
    #[arg(long, default_value_t = 0.0)]
    pub link_jitter_us: f64,
    /// Emulated loss: the fraction of datagrams dropped, 0..=1.
    #[arg(long, default_value_t = 0.0)]
    pub link_loss: f64,
    /// Seed of the emulated jitter and loss.
    #[arg(long, default_value_t = 1)]
    pub link_seed: u64,
    /// The near bridge polls this long for the reply after sending a state before it blocks, µs
    /// (0: it blocks at once; at most loop.torque_budget_us in realtime).
    #[arg(long, default_value_t = 0)]
    pub link_spin_us: u32,
    /// How the loop's messages cross: `direct` (plant and controller socket to socket; the
    /// default) or `relay` (through both bridges).
    #[arg(long, value_parser = parse_link_path)]
    pub link_path: Option<deltaloop_config::LinkPath>,
}

/// `--link-path`: `direct` or `relay`.
fn parse_link_path(s: &str) -> Result<deltaloop_config::LinkPath, String> {
    use deltaloop_config::LinkPath;
    match s {
        "direct" => Ok(LinkPath::Direct),
        "relay" => Ok(LinkPath::Relay),
        _ => Err(format!("{s:?}: allowed direct, relay")),
    }
}

impl EmuArgs {
    /// The emulation; one line naming the field otherwise.
    pub fn emulation(&self) -> Result<emulation::Emulation> {
        let us = |what: &str, v: f64| -> Result<u64> {
            let max = deltaloop_config::MAX_LINK_DELAY_US;
            if !(v.is_finite() && (0.0..=max).contains(&v)) {
                bail!("--{what} {v}: allowed 0..={max} µs");
            }
            Ok((v * 1000.0).round() as u64)
        };
        if !(self.link_loss.is_finite() && (0.0..=1.0).contains(&self.link_loss)) {
            bail!("--link-loss {}: allowed 0..=1 (a fraction)", self.link_loss);
        }
        Ok(emulation::Emulation {
            delay_ns: us("link-delay-us", self.link_delay_us)?,
            jitter_ns: us("link-jitter-us", self.link_jitter_us)?,
            loss_ppm: (self.link_loss * 1e6).round() as u32,
            seed: self.link_seed,
        })
    }
}

/// Which process of a run split over two hosts runs on the far host (`deltaloop join --role`):
/// the near side stands in for it on the supervisor's host, the far side starts it.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Role {
    /// `--controller-remote`: the controller there, the plant and the supervisor here.
    Controller,
    /// `--plant-remote`: the plant there, the controller and the supervisor here.
    Plant,
}

impl Role {
    /// The word: on the command line and in the HELLO.
    pub fn name(self) -> &'static str {
        match self {
            Role::Controller => "controller",
            Role::Plant => "plant",
        }
    }

    /// The role as a JOIN frame carries it (1 controller, 2 plant).
    pub fn to_wire(self) -> u32 {
        match self {
            Role::Controller => 1,
            Role::Plant => 2,
        }
    }

    /// The role of a JOIN frame's value (None: neither).
    pub fn from_wire(v: u32) -> Option<Self> {
        [Role::Controller, Role::Plant]
            .into_iter()
            .find(|r| r.to_wire() == v)
    }

    /// The role of the config's `[link] remote`.
    pub fn of(side: deltaloop_config::RemoteSide) -> Self {
        match side {
            deltaloop_config::RemoteSide::Controller => Role::Controller,
            deltaloop_config::RemoteSide::Plant => Role::Plant,
        }
    }

    /// The config's `[link] remote` of this role.
    pub fn side(self) -> deltaloop_config::RemoteSide {
        match self {
            Role::Controller => deltaloop_config::RemoteSide::Controller,
            Role::Plant => deltaloop_config::RemoteSide::Plant,
        }
    }

    /// Parses a word; None if it is neither role.
    pub fn parse(s: &str) -> Option<Self> {
        [Role::Controller, Role::Plant]
            .into_iter()
            .find(|r| r.name() == s)
    }
}

impl std::fmt::Display for Role {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.pad(self.name())
    }
}

/// `HOST:PORT` (an IPv4 or IPv6 address or a host name, and a port 1..=65535) → its first address.
pub fn parse_endpoint(s: &str) -> Result<SocketAddr, String> {
    let shown: String = deltaloop_transport::wire::escape_peer_text(s)
        .chars()
        .take(100)
        .collect();
    let bad =
        |why: &str| format!("endpoint `{shown}`: {why} (expected HOST:PORT, e.g. 10.0.0.1:7447)");
    let (host, port) = s.rsplit_once(':').ok_or_else(|| bad("no port"))?;
    let port: u16 = port.parse().map_err(|_| bad("the port is not 1..=65535"))?;
    if port == 0 {
        return Err(bad("the port is not 1..=65535"));
    }
    if host.is_empty() {
        return Err(bad("no host"));
    }
    let host = host.trim_start_matches('[').trim_end_matches(']');
    (host, port)
        .to_socket_addrs()
        .map_err(|e| bad(&format!("cannot resolve the host: {e}")))?
        .next()
        .ok_or_else(|| bad("the host has no address"))
}

/// On the direct path a bridge is control plane only: it moves itself off the CPU of the loop
/// process beside it (`cpu`, from the run's layout; None: not pinned, nothing to do), onto every
/// other CPU this process may use, so its wake-ups (the record's copies every millisecond, its
/// TCP traffic and that traffic's kernel work) never delay the loop's. Best effort: a host with
/// one CPU keeps it. Returns the CPU it left, for its log.
pub fn keep_off(cpu: Option<usize>) -> Option<usize> {
    let cpu = cpu?;
    // SAFETY: cpu_set_t is plain data; sched_getaffinity/setaffinity write/read the set we own.
    unsafe {
        let mut set: libc::cpu_set_t = std::mem::zeroed();
        if libc::sched_getaffinity(0, size_of::<libc::cpu_set_t>(), &mut set) != 0
            || cpu >= libc::CPU_SETSIZE as usize
            || !libc::CPU_ISSET(cpu, &set)
            || libc::CPU_COUNT(&set) < 2
        {
            return None;
        }
        libc::CPU_CLR(cpu, &mut set);
        (libc::sched_setaffinity(0, size_of::<libc::cpu_set_t>(), &set) == 0).then_some(cpu)
    }
}

/// How long a bridge polls for the reply after passing a state on, ns (`--spin-us`, at most the
/// torque budget in realtime: a reply later than that is late anyway). Polling saves the wake-up
/// of a blocked bridge (tens of µs on a VM) but takes a CPU: on one machine hosting both sides,
/// two polling bridges take turns on the one CPU the loop leaves them.
pub fn spin_ns(
    config: &std::path::Path,
    mode: deltaloop_config::LoopMode,
    spin_us: u32,
) -> Result<u64> {
    spin_ns_of(
        &deltaloop_config::RunConfig::from_file(config)?,
        mode,
        spin_us,
    )
}

/// [`spin_ns`] of a config already read.
pub fn spin_ns_of(
    cfg: &deltaloop_config::RunConfig,
    mode: deltaloop_config::LoopMode,
    spin_us: u32,
) -> Result<u64> {
    if mode.layout(cfg).is_none() {
        bail!("mode {mode} has no processes");
    }
    let budget_us = cfg.loop_.torque_budget_us;
    if mode == deltaloop_config::LoopMode::Realtime && spin_us > budget_us {
        bail!("--spin-us {spin_us}: allowed 0..={budget_us} (loop.torque_budget_us)");
    }
    Ok(u64::from(spin_us) * 1000)
}

/// The folder of this executable (where `deltaloop-controller` and `deltaloop-plant` are looked
/// for).
pub fn exe_dir() -> Result<std::path::PathBuf> {
    let exe = std::env::current_exe()?;
    Ok(exe
        .parent()
        .map(std::path::Path::to_path_buf)
        .unwrap_or_default())
}

/// Entry point of `deltaloop-bridge`.
pub fn main() -> ExitCode {
    let cli = Cli::parse();
    let term = deltaloop_transport::rt::child_signals();
    // SAFETY: setting this process's own timer slack (1 ns: the waits are µs-exact).
    unsafe { libc::prctl(libc::PR_SET_TIMERSLACK, 1 as libc::c_ulong, 0, 0, 0) };
    let far_side = matches!(cli.side, Side::Far(_));
    if far_side {
        // On the far host Ctrl-C is the user's: a clean stop of the process there.
        let _ = signal_hook_register_int(&term);
    }
    let r = match &cli.side {
        Side::Near(a) => near::run(a, &term),
        Side::Far(a) => far::run(a, &term),
        Side::Ping(a) => ping::ping(a).map(|()| (0, None)),
        Side::Pong(a) => ping::pong(a, &term).map(|()| (0, None)),
        #[cfg(feature = "zenoh")]
        Side::Zping(a) => zping::zping(a).map(|()| (0, None)),
        #[cfg(feature = "zenoh")]
        Side::Zpong(a) => zping::zpong(a, &term).map(|()| (0, None)),
    };
    match r {
        Ok((0, _)) => ExitCode::SUCCESS,
        Ok((code, line)) => {
            eprintln!("{NAME}: {}", line.unwrap_or_else(|| format!("exit {code}")));
            ExitCode::from(code)
        }
        Err(e) => {
            eprintln!("{NAME}: {e:#}");
            ExitCode::from(deltaloop_transport::exit::EXIT_SETUP)
        }
    }
}

fn signal_hook_register_int(term: &std::sync::Arc<std::sync::atomic::AtomicBool>) -> Result<()> {
    // SAFETY: restoring SIGINT's default disposition before registering a handler for it.
    unsafe { libc::signal(libc::SIGINT, libc::SIG_DFL) };
    signal_hook::flag::register(signal_hook::consts::SIGINT, term.clone())?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn endpoints_are_checked_with_one_line() {
        assert_eq!(
            parse_endpoint("127.0.0.1:7447").unwrap(),
            "127.0.0.1:7447".parse().unwrap()
        );
        assert!(parse_endpoint("[::1]:7447").is_ok());
        for (bad, says) in [
            ("10.0.0.1", "no port"),
            ("10.0.0.1:0", "1..=65535"),
            ("10.0.0.1:70000", "1..=65535"),
            (":7447", "no host"),
            ("no.such.host.invalid:7447", "cannot resolve"),
        ] {
            let e = parse_endpoint(bad).unwrap_err();
            assert!(
                e.contains(says) && e.contains("HOST:PORT") && !e.contains('\n'),
                "{e}"
            );
        }
        let e = EmuArgs {
            link_loss: 2.0,
            ..Default::default()
        }
        .emulation()
        .unwrap_err()
        .to_string();
        assert!(e.contains("--link-loss 2") && e.contains("0..=1"), "{e}");
    }
}
