//! The real-time helpers both loop processes share: the monotonic clock, absolute sleeps, and
//! scheduling (CPU pinning, SCHED_FIFO, mlockall, timer slack) with warnings where not permitted.

use deltaloop_config::{Poll, Priority};

/// CLOCK_MONOTONIC now, ns.
#[inline]
pub fn now_ns() -> u64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: clock_gettime writes into the timespec we own; CLOCK_MONOTONIC always exists on Linux.
    unsafe { libc::clock_gettime(libc::CLOCK_MONOTONIC, &mut ts) };
    ts.tv_sec as u64 * 1_000_000_000 + ts.tv_nsec as u64
}

/// Sleeps until the absolute CLOCK_MONOTONIC time `t_ns` (clock_nanosleep, TIMER_ABSTIME), so
/// periods do not drift; retries on signal interruption.
#[inline]
pub fn sleep_until_ns(t_ns: u64) {
    let ts = libc::timespec {
        tv_sec: (t_ns / 1_000_000_000) as libc::time_t,
        tv_nsec: (t_ns % 1_000_000_000) as libc::c_long,
    };
    loop {
        // SAFETY: a valid timespec; a null remainder is allowed with TIMER_ABSTIME.
        let r = unsafe {
            libc::clock_nanosleep(
                libc::CLOCK_MONOTONIC,
                libc::TIMER_ABSTIME,
                &ts,
                std::ptr::null_mut(),
            )
        };
        if r != libc::EINTR {
            return;
        }
    }
}

/// Wakes at `t_ns` precisely: sleeps until `early_ns` before it, then busy-waits the rest (never
/// yielding: a peer given the CPU now would make this wake-up late by its time slice).
#[inline]
pub fn wake_at_ns(t_ns: u64, early_ns: u64) {
    if early_ns > 0 {
        sleep_until_ns(t_ns.saturating_sub(early_ns));
        while now_ns() < t_ns {
            std::hint::spin_loop();
        }
    } else {
        sleep_until_ns(t_ns);
    }
}

/// One pause between two looks for a peer's message: a spin-loop hint on this CPU, or a
/// `sched_yield` that lets a peer of the same priority on this CPU run (`poll = "yield"`).
#[inline]
pub fn poll_pause(poll: Poll) {
    match poll {
        Poll::Spin => std::hint::spin_loop(),
        Poll::Yield => std::thread::yield_now(),
    }
}

/// Busy-waits `us` microseconds (the injected compute delay); reads only the clock.
#[inline]
pub fn spin_for_us(us: u32) {
    let end = now_ns() + u64::from(us) * 1000;
    while now_ns() < end {
        std::hint::spin_loop();
    }
}

/// The share of each period the kernel lets SCHED_FIFO tasks take on a CPU before it runs the
/// others waiting there (`sched_rt_runtime_us` / `sched_rt_period_us`, 0.95 by default); None
/// when unlimited (−1) or unreadable.
pub fn rt_share_limit() -> Option<f64> {
    let read = |f: &str| -> Option<i64> {
        std::fs::read_to_string(format!("/proc/sys/kernel/{f}"))
            .ok()?
            .trim()
            .parse()
            .ok()
    };
    let (runtime, period) = (read("sched_rt_runtime_us")?, read("sched_rt_period_us")?);
    (runtime >= 0 && period > 0).then(|| runtime as f64 / period as f64)
}

/// How one process should be scheduled.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sched {
    /// Pin to this CPU (None: leave the affinity alone).
    pub core: Option<usize>,
    /// SCHED_FIFO at a priority, or SCHED_OTHER left as it is.
    pub priority: Priority,
    /// mlockall(MCL_CURRENT | MCL_FUTURE).
    pub lock_memory: bool,
}

/// Applies `s` to the calling process/thread. Returns one line per thing that was not permitted
/// (the process runs on with the fallback); never fails.
pub fn apply(s: &Sched) -> Vec<String> {
    let mut warnings = Vec::new();
    // SAFETY: plain prctl/sched/mlock syscalls on the calling process with valid arguments.
    unsafe {
        // Timer slack 1 ns: absolute sleeps wake as close to the deadline as the kernel can.
        libc::prctl(libc::PR_SET_TIMERSLACK, 1 as libc::c_ulong, 0, 0, 0);
    }
    if let Some(core) = s.core {
        let n = core_affinity::get_core_ids().map_or(0, |v| v.len());
        if !core_affinity::set_for_current(core_affinity::CoreId { id: core }) {
            warnings.push(format!(
                "cannot pin to CPU {core} (this machine has {n}): running unpinned"
            ));
        }
    }
    if let Priority::Fifo(p) = s.priority {
        let param = libc::sched_param {
            sched_priority: i32::from(p),
        };
        // SAFETY: as above.
        if unsafe { libc::sched_setscheduler(0, libc::SCHED_FIFO, &param) } != 0 {
            let e = std::io::Error::last_os_error();
            warnings.push(format!(
                "SCHED_FIFO priority {p} not permitted ({e}; needs root, CAP_SYS_NICE or an rtprio limit): running SCHED_OTHER"
            ));
        }
    }
    // SAFETY: as above.
    if s.lock_memory && unsafe { libc::mlockall(libc::MCL_CURRENT | libc::MCL_FUTURE) } != 0 {
        let e = std::io::Error::last_os_error();
        warnings.push(format!(
            "mlockall not permitted ({e}): pages may fault in the loop"
        ));
    }
    warnings
}

/// Signal set-up for a loop process started by the supervisor: SIGINT and SIGHUP are ignored (a
/// Ctrl-C, or the terminal closing, reaches the whole process group; the supervisor stops its
/// children in order),
/// SIGTERM sets the returned flag (checked once per tick: a clean stop), and the process gets
/// SIGTERM if its parent dies, so no child outlives a killed supervisor.
pub fn child_signals() -> std::sync::Arc<std::sync::atomic::AtomicBool> {
    let flag = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    // SAFETY: setting a signal disposition and the parent-death signal of this process.
    unsafe {
        libc::signal(libc::SIGINT, libc::SIG_IGN);
        libc::signal(libc::SIGHUP, libc::SIG_IGN);
        libc::prctl(
            libc::PR_SET_PDEATHSIG,
            libc::SIGTERM as libc::c_ulong,
            0,
            0,
            0,
        );
    }
    let _ = signal_hook::flag::register(signal_hook::consts::SIGTERM, flag.clone());
    flag
}

/// Makes `cmd` a child that does not outlive this process: it starts with SIGINT and SIGHUP
/// ignored (kept across exec: a Ctrl-C or a hang-up reaches the whole process group, possibly
/// before the child has set up its own handling, and the parent stops its children in order),
/// gets SIGTERM when this process dies (a parent killed outright, SIGKILL or the OOM killer,
/// cannot stop it: regression, a SIGKILLed supervisor left its plant running to the scenario's
/// end), and does not start at all if this process died before that was set.
pub fn die_with_parent(cmd: &mut std::process::Command) {
    use std::os::unix::process::CommandExt;
    let parent = std::process::id() as libc::pid_t;
    // SAFETY: signal(), prctl() and getppid() are async-signal-safe; nothing else runs between
    // fork and exec.
    unsafe {
        cmd.pre_exec(move || {
            libc::signal(libc::SIGINT, libc::SIG_IGN);
            libc::signal(libc::SIGHUP, libc::SIG_IGN);
            libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGTERM);
            if libc::getppid() != parent {
                return Err(std::io::Error::other("the parent is gone"));
            }
            Ok(())
        });
    }
}

/// A loop process's start: apply its scheduling, print one warning line per thing not permitted
/// (prefixed with the process name), then tell the supervisor it is ready.
pub fn schedule_and_report_ready<E>(
    s: &Sched,
    name: &str,
    ready: impl FnOnce() -> Result<(), E>,
) -> Result<(), E> {
    for w in apply(s) {
        eprintln!("{name}: warning: {w}");
    }
    ready()
}
