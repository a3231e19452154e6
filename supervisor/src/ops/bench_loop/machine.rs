//! The machine's own limit at the loop's period, CPU and priority: a sleep-only wake-up loop (what
//! cyclictest measures) and `cyclictest` itself when it is installed.

use anyhow::Result;
use deltaloop_config::Priority;
use deltaloop_transport::rt;
use hdrhistogram::Histogram;

/// The machine's own limit, as cyclictest measures it: a thread on `cpu` at `prio`
/// sleeps to absolute deadlines every `ts_ns` for `seconds`; the histogram of its wake
/// lateness (ns). Memory is locked and allocated before the loop, as in the plant.
pub fn sleep_only_loop(
    cpu: usize,
    prio: Priority,
    ts_ns: u64,
    seconds: f64,
) -> Result<Histogram<u64>> {
    let n = (seconds * 1e9 / ts_ns as f64).round() as u64;
    let t = std::thread::spawn(move || {
        let warnings = rt::apply(&rt::Sched {
            core: Some(cpu),
            priority: prio,
            lock_memory: false,
        });
        let mut h = deltaloop_timing::latency_histogram();
        let t0 = rt::now_ns() + 1_000_000;
        for k in 0..n {
            let d = t0 + k * ts_ns;
            rt::sleep_until_ns(d);
            let _ = h.record(rt::now_ns().saturating_sub(d).max(1));
        }
        (h, warnings)
    });
    let (h, warnings) = t
        .join()
        .map_err(|_| anyhow::anyhow!("the sleep-only loop panicked"))?;
    for w in warnings {
        eprintln!("deltaloop bench loop: warning: {w}");
    }
    Ok(h)
}

/// `cyclictest` (rt-tests) with the same CPU, priority and period, if it is installed; its
/// latency histogram in ns (1 µs buckets; overflows beyond 10 ms counted at 10 ms).
pub fn cyclictest(
    cpu: usize,
    prio: Priority,
    interval_us: u64,
    seconds: f64,
) -> Result<Histogram<u64>, String> {
    let o = std::process::Command::new("cyclictest")
        .args(["-m", "-q", "-t", "1", "-h", "10000"])
        .args(["-p", &prio.key_value().to_string(), "-a", &cpu.to_string()])
        .args(["-i", &interval_us.to_string()])
        .args(["-D", &format!("{}", seconds.ceil() as u64)])
        .stdin(std::process::Stdio::null())
        .output()
        .map_err(|e| format!("{e}; install rt-tests for it"))?;
    if !o.status.success() {
        return Err(format!(
            "exit {}: {}",
            o.status,
            String::from_utf8_lossy(&o.stderr).trim()
        ));
    }
    parse_cyclictest_histogram(&String::from_utf8_lossy(&o.stdout))
}

/// cyclictest's `-h` output: lines "<µs> <count>" and comments; overflows go to the top bucket.
fn parse_cyclictest_histogram(text: &str) -> Result<Histogram<u64>, String> {
    let mut h = deltaloop_timing::latency_histogram();
    for line in text.lines() {
        if let Some(rest) = line.strip_prefix("# Histogram Overflows:") {
            let n: u64 = rest.trim().parse().unwrap_or(0);
            let _ = h.record_n(10_000_000, n);
            continue;
        }
        let mut f = line.split_whitespace();
        if let (Some(us), Some(count), None) = (f.next(), f.next(), f.next())
            && let (Ok(us), Ok(count)) = (us.parse::<u64>(), count.parse::<u64>())
        {
            let _ = h.record_n((us * 1000).max(1), count);
        }
    }
    if h.is_empty() {
        return Err("no histogram in its output".into());
    }
    Ok(h)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cyclictest_histogram_is_read_in_microseconds_with_overflows_at_the_top() {
        let text = "# /dev/cpu_dma_latency set to 0us\n000000 000000\n000003 000010\n000004 000089\n000120 000001\n# Total: 000000101\n# Min Latencies: 00003\n# Histogram Overflows: 00002\n";
        let h = parse_cyclictest_histogram(text).unwrap();
        assert_eq!(h.len(), 102);
        assert_eq!(h.value_at_quantile(0.5), h.highest_equivalent(4_000));
        assert!(h.max() >= 10_000_000);
        assert!(parse_cyclictest_histogram("# nothing\n").is_err());
    }
}
