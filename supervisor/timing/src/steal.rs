//! CPU time the hypervisor took from this machine (`steal` in /proc/stat), per CPU.

use super::*;

/// Per-CPU "steal" time from /proc/stat: time the hypervisor ran something else while this
/// (virtual) CPU had work. On a VM it explains stalls no scheduling policy inside the guest can
/// prevent. Jiffies, per CPU index; empty where /proc/stat is unavailable.
pub fn steal_jiffies() -> Vec<(usize, u64)> {
    let Ok(text) = std::fs::read_to_string("/proc/stat") else {
        return Vec::new();
    };
    text.lines()
        .filter_map(|l| {
            let mut f = l.split_whitespace();
            let cpu = f.next()?.strip_prefix("cpu")?.parse::<usize>().ok()?;
            // user nice system idle iowait irq softirq steal
            let steal = f.nth(7)?.parse::<u64>().ok()?;
            Some((cpu, steal))
        })
        .collect()
}

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
