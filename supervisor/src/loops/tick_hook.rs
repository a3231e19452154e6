//! A process-wide hook on the supervisor's finished ticks: `deltaloop soak` watches its own run
//! through it (progress and per-minute summaries) without a second observer on the loop, so the
//! run's spare observer slot stays free for `deltaloop top`. The process modes call [`call`] for
//! every tick they finish, in tick order, right after the tick went to the run's timing
//! histograms (`procs::Observation::finish_tick`); without a hook that costs one atomic load.

use crate::timing::Seen;
use std::sync::Mutex;
use std::sync::atomic::{AtomicBool, Ordering};

type Hook = Box<dyn FnMut(&Seen) + Send>;

static ACTIVE: AtomicBool = AtomicBool::new(false);
static HOOK: Mutex<Option<Hook>> = Mutex::new(None);

/// Removes the hook when dropped.
pub struct Installed(());

impl Drop for Installed {
    fn drop(&mut self) {
        ACTIVE.store(false, Ordering::Release);
        if let Ok(mut h) = HOOK.lock() {
            *h = None;
        }
    }
}

/// Installs `hook` (replacing any other) until the returned guard is dropped.
#[must_use = "the hook is removed when the guard is dropped"]
pub fn install(hook: impl FnMut(&Seen) + Send + 'static) -> Installed {
    if let Ok(mut h) = HOOK.lock() {
        *h = Some(Box::new(hook));
    }
    ACTIVE.store(true, Ordering::Release);
    Installed(())
}

/// Hands a finished tick to the hook, if one is installed.
pub fn call(seen: &Seen) {
    if !ACTIVE.load(Ordering::Acquire) {
        return;
    }
    if let Ok(mut h) = HOOK.lock()
        && let Some(f) = h.as_mut()
    {
        f(seen);
    }
}
