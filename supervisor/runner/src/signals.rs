//! Ctrl-C, SIGTERM and SIGHUP (the terminal closed): the supervisor stops its children in order
//! and keeps the data so far. The first such signal is remembered, so the exit line can name it.

use std::sync::Arc;
use std::sync::OnceLock;
use std::sync::atomic::{AtomicUsize, Ordering};

static SIGNAL: OnceLock<Arc<AtomicUsize>> = OnceLock::new();

/// The signals that stop a run.
const STOPPING: [i32; 3] = [
    signal_hook::consts::SIGINT,
    signal_hook::consts::SIGTERM,
    signal_hook::consts::SIGHUP,
];

/// Registers SIGINT, SIGTERM and SIGHUP (once); afterwards [`interrupted`] reports them.
pub fn install() {
    let flag = SIGNAL.get_or_init(|| Arc::new(AtomicUsize::new(0)));
    for sig in STOPPING {
        let _ = signal_hook::flag::register_usize(sig, flag.clone(), sig as usize);
    }
}

/// Whether a stopping signal arrived since [`install`].
pub fn interrupted() -> bool {
    signal().is_some()
}

/// The last stopping signal that arrived, if any.
pub fn signal() -> Option<i32> {
    SIGNAL
        .get()
        .map(|f| f.load(Ordering::Relaxed) as i32)
        .filter(|&s| s != 0)
}

/// A signal's name for messages (`SIGINT`, …).
pub fn name(sig: i32) -> String {
    match sig {
        signal_hook::consts::SIGINT => "SIGINT".into(),
        signal_hook::consts::SIGTERM => "SIGTERM".into(),
        signal_hook::consts::SIGHUP => "SIGHUP".into(),
        s => format!("signal {s}"),
    }
}

/// The variable a parent sets to its own pid to have `deltaloop` stop with it.
pub const PARENT_PID_ENV: &str = "DELTALOOP_PARENT_PID";

/// With `DELTALOOP_PARENT_PID=<pid>` (a Python driver or Dask task sets it): the kernel sends
/// SIGTERM when the parent dies, so a SIGKILLed parent does not leave `deltaloop` (and its plant
/// and controller) running as orphans; SIGTERM then stops the run in order. Err with one line if
/// the value is not a pid, or that process is no longer the parent. The variable is removed, so
/// `deltaloop`'s own children do not inherit it. Call before any thread starts.
pub fn die_with_parent_from_env() -> Result<(), String> {
    let Some(v) = std::env::var_os(PARENT_PID_ENV) else {
        return Ok(());
    };
    // SAFETY: called first thing in main, before any other thread exists.
    unsafe { std::env::remove_var(PARENT_PID_ENV) };
    let v = v.to_string_lossy();
    let pid: libc::pid_t = v.trim().parse().ok().filter(|&p| p > 1).ok_or_else(|| {
        format!("{PARENT_PID_ENV} = `{v}` is not a process id (expected the parent's pid, > 1)")
    })?;
    // SAFETY: prctl and getppid act on this process only.
    unsafe { libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGTERM) };
    let parent = unsafe { libc::getppid() };
    if parent != pid {
        return Err(format!(
            "{PARENT_PID_ENV} = {pid}, but the parent is process {parent}: the process that started deltaloop is gone"
        ));
    }
    Ok(())
}
