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
