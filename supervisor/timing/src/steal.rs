//! CPU time the hypervisor took from this machine (`steal` in /proc/stat), per CPU.

use super::*;

/// Per-CPU "steal" time from /proc/stat: time the hypervisor ran something else while this
/// (virtual) CPU had work. On a VM it explains stalls no scheduling policy inside the guest can
/// prevent. Jiffies, per CPU index; empty where /proc/stat is unavailable.
pub use deltaloop_sched::steal_jiffies;

/// Steal time per CPU between two readings, ms.
pub fn steal_ms_between(before: &[(usize, u64)], after: &[(usize, u64)]) -> Vec<StealMs> {
    // SAFETY: sysconf has no preconditions.
    let hz = unsafe { libc::sysconf(libc::_SC_CLK_TCK) }.max(1) as f64;
    after
        .iter()
        .filter_map(|&(cpu, a)| {
            let b = before.iter().find(|(c, _)| *c == cpu)?.1;
            Some(StealMs {
                cpu,
                ms: a.saturating_sub(b) as f64 * 1e3 / hz,
            })
        })
        .collect()
}

/// Steal time of one CPU over a run.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct StealMs {
    pub cpu: usize,
    pub ms: f64,
}
