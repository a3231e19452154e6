//! deltaloop-bridge: one run's iceoryx2 services carried between two hosts.
//!
//! The loop's messages (state out, torque back) travel as one UDP datagram each, the `#[repr(C)]`
//! wire type byte for byte behind a 24-byte header and sealed with a 16-byte tag ([`frame`]); run control, the reference chunks,
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

pub mod cli;
pub mod far;
pub mod hello;
pub mod link;
pub mod near;
pub mod ping;
pub mod seal;
pub mod sides;
#[cfg(feature = "zenoh")]
pub mod zping;

pub use deltaloop_link::{bytes, direct, emulation, frame, replies};
pub use deltaloop_link_setup::parse_endpoint;

use anyhow::{Result, bail};
use deltaloop_config::RemoteSide;
use std::process::ExitCode;

const NAME: &str = "deltaloop-bridge";

/// The remote side (`[link] remote`, `far --role`) as a JOIN frame carries it: 1 controller, 2
/// plant.
pub fn side_to_wire(side: RemoteSide) -> u32 {
    match side {
        RemoteSide::Controller => 1,
        RemoteSide::Plant => 2,
    }
}

/// The remote side of a JOIN frame's value (None: neither).
pub fn side_from_wire(v: u32) -> Option<RemoteSide> {
    RemoteSide::ALL
        .iter()
        .copied()
        .find(|&s| side_to_wire(s) == v)
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
    let cli = cli::Cli::from_args();
    let term = deltaloop_transport::rt::child_signals();
    // SAFETY: setting this process's own timer slack (1 ns: the waits are µs-exact).
    unsafe { libc::prctl(libc::PR_SET_TIMERSLACK, 1 as libc::c_ulong, 0, 0, 0) };
    let far_side = matches!(cli.side, cli::Side::Far(_));
    if far_side {
        // On the far host Ctrl-C is the user's: a clean stop of the process there.
        let _ = signal_hook_register_int(&term);
    }
    let r = match &cli.side {
        cli::Side::Near(a) => near::run(a, &term),
        cli::Side::Far(a) => far::run(a, &term),
        cli::Side::Ping(a) => ping::ping(a).map(|()| (0, None)),
        cli::Side::Pong(a) => ping::pong(a, &term).map(|()| (0, None)),
        #[cfg(feature = "zenoh")]
        cli::Side::Zping(a) => zping::zping(a).map(|()| (0, None)),
        #[cfg(feature = "zenoh")]
        cli::Side::Zpong(a) => zping::zpong(a, &term).map(|()| (0, None)),
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
