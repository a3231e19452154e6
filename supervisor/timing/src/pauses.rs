//! The plant's pauses of simulated time (`overrun = "stretch"`), read off its telemetry: each
//! tick's deadline is t0 + (the pauses so far) + k·Ts, so a deadline later than the previous one
//! plus the ticks between is a pause of that length. The host's steal around each pause comes
//! from `/proc/stat`, sampled by the supervisor while the loop runs.

use serde::Serialize;

/// Pauses kept one by one in `summary.json` (the count and total cover them all).
pub const MAX_LISTED: usize = 64;

/// Steal samples kept (at [`STEAL_EVERY_NS`], 41 s: more than the observer's window of open
/// ticks, so a pause is looked up before its samples are overwritten).
const STEAL_SAMPLES: usize = 2048;

/// How often the supervisor samples the host's steal while a realtime loop runs, ns.
pub const STEAL_EVERY_NS: u64 = 20_000_000;

/// One pause of simulated time: the plant's own process woke for `tick` this much later than
/// its deadline, beyond the overrun bound, and the epoch moved by it.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct Pause {
    /// The first tick after the pause.
    pub tick: u64,
    /// Simulated time t_k = k·Ts of that tick, s.
    pub t_s: f64,
    /// How long simulated time stood still, ms (wall time).
    pub ms: f64,
    /// What the hypervisor stole from this machine's CPUs (all together) in the sampling
    /// interval around the pause, ms; None where `/proc/stat` has no steal.
    pub host_steal_ms: Option<f64>,
}

/// The host's steal over all CPUs, sampled every [`STEAL_EVERY_NS`]: (CLOCK_MONOTONIC ns,
/// jiffies), a ring.
#[derive(Debug, Clone)]
pub struct StealLog {
    samples: Vec<(u64, u64)>,
    next: usize,
    last_ns: u64,
    ms_per_jiffy: f64,
}

impl Default for StealLog {
    fn default() -> Self {
        // SAFETY: sysconf has no preconditions.
        let hz = unsafe { libc::sysconf(libc::_SC_CLK_TCK) }.max(1) as f64;
        Self {
            samples: Vec::with_capacity(STEAL_SAMPLES),
            next: 0,
            last_ns: 0,
            ms_per_jiffy: 1e3 / hz,
        }
    }
}

impl StealLog {
    /// Takes a sample at `now_ns` unless one was taken less than [`STEAL_EVERY_NS`] ago and
    /// this is not the `last`.
    pub fn sample(&mut self, now_ns: u64, last: bool) {
        if !last && self.last_ns != 0 && now_ns < self.last_ns + STEAL_EVERY_NS {
            return;
        }
        self.force(now_ns, super::steal_jiffies().iter().map(|c| c.1).sum());
    }

    /// Records `jiffies` of steal (all CPUs) at `now_ns`.
    fn force(&mut self, now_ns: u64, jiffies: u64) {
        self.last_ns = now_ns;
        if self.samples.len() < STEAL_SAMPLES {
            self.samples.push((now_ns, jiffies));
        } else {
            self.samples[self.next] = (now_ns, jiffies);
        }
        self.next = (self.next + 1) % STEAL_SAMPLES;
    }

    /// Steal between the last sample at or before `from_ns` and the first at or after `to_ns`,
    /// ms; None if the samples do not cover the interval.
    fn between(&self, from_ns: u64, to_ns: u64) -> Option<f64> {
        let before = self
            .samples
            .iter()
            .filter(|s| s.0 <= from_ns)
            .max_by_key(|s| s.0)?;
        let after = self
            .samples
            .iter()
            .filter(|s| s.0 >= to_ns)
            .min_by_key(|s| s.0)?;
        Some(after.1.saturating_sub(before.1) as f64 * self.ms_per_jiffy)
    }
}

/// The pauses of one run, counted from its telemetry in tick order.
#[derive(Debug, Clone, Default)]
pub struct Pauses {
    /// The last tick with telemetry and its deadline, ns.
    prev: Option<(u64, u64)>,
    /// Every pause, counted.
    pub count: u64,
    /// Their total, ns.
    pub total_ns: u64,
    /// The longest: (ns, tick).
    pub longest: Option<(u64, u64)>,
    /// The first [`MAX_LISTED`], with the steal around each when the steal was sampled.
    pub listed: Vec<Pause>,
    /// The simulated span of the ticks seen, in deadlines: (first, last) tick.
    span: Option<(u64, u64)>,
}

impl Pauses {
    /// Tick k's deadline (ns, from its telemetry) at period `ts_ns`; a pause is one where the
    /// deadline moved later than the ticks since the last telemetry account for.
    pub fn tick(&mut self, k: u64, deadline_ns: u64, ts_ns: u64, steal: Option<&StealLog>) {
        if self.listed.capacity() == 0 {
            self.listed.reserve_exact(MAX_LISTED);
        }
        self.span = Some(self.span.map_or((k, k), |(a, _)| (a, k)));
        if let Some((j, dj)) = self.prev.filter(|(j, _)| *j < k) {
            let due = dj + (k - j) * ts_ns;
            let ns = deadline_ns.saturating_sub(due);
            if ns > 0 {
                self.count += 1;
                self.total_ns += ns;
                if self.longest.is_none_or(|(l, _)| ns > l) {
                    self.longest = Some((ns, k));
                }
                if self.listed.len() < MAX_LISTED {
                    self.listed.push(Pause {
                        tick: k,
                        t_s: k as f64 * ts_ns as f64 * 1e-9,
                        ms: ns as f64 / 1e6,
                        host_steal_ms: steal.and_then(|s| s.between(due, deadline_ns)),
                    });
                }
            }
        }
        self.prev = Some((k, deadline_ns));
    }

    /// Simulated time over wall time of the ticks seen: Δk·Ts / (Δk·Ts + pauses); 1 with no
    /// pause (the plant kept to the wall clock), None before two ticks.
    pub fn realtime_factor(&self, ts_ns: u64) -> Option<f64> {
        let (a, b) = self.span.filter(|(a, b)| b > a)?;
        let sim = (b - a) as f64 * ts_ns as f64;
        Some(sim / (sim + self.total_ns as f64))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const TS: u64 = 300_000;

    /// A stretched run's deadlines: t0 + pauses + k·Ts. The pauses come back tick, length and
    /// steal; a missing telemetry in between does not make one; catch-up deadlines make none.
    #[test]
    fn pauses_are_read_off_the_deadlines() {
        let t0 = 1_000_000_000;
        let mut steal = StealLog::default();
        steal.force(t0, 100);
        steal.force(t0 + 200 * TS, 103);
        let mut p = Pauses::default();
        for k in 0..1000u64 {
            let paused = match k {
                0..=99 => 0,
                100..=499 => 10_300_000,
                _ => 10_300_000 + 2_000_000,
            };
            if k == 300 {
                continue; // telemetry lost
            }
            p.tick(k, t0 + paused + k * TS, TS, Some(&steal));
        }
        assert_eq!(p.count, 2);
        assert_eq!(p.total_ns, 12_300_000);
        assert_eq!(p.longest, Some((10_300_000, 100)));
        assert_eq!(p.listed[0].tick, 100);
        assert_eq!(p.listed[0].ms, 10.3);
        assert!((p.listed[0].t_s - 0.03).abs() < 1e-12);
        let ms_per_jiffy = steal.ms_per_jiffy;
        assert_eq!(p.listed[0].host_steal_ms, Some(3.0 * ms_per_jiffy));
        assert_eq!(p.listed[1].host_steal_ms, None, "no sample after it");
        let rtf = p.realtime_factor(TS).unwrap();
        let sim = 999.0 * TS as f64;
        assert!((rtf - sim / (sim + 12.3e6)).abs() < 1e-15, "{rtf}");
        let mut c = Pauses::default();
        for k in 0..1000u64 {
            c.tick(k, t0 + k * TS, TS, None);
        }
        assert_eq!((c.count, c.realtime_factor(TS)), (0, Some(1.0)));
    }

    #[test]
    fn only_the_first_pauses_are_listed_and_all_are_counted() {
        let mut p = Pauses::default();
        let mut d = 0;
        for k in 0..(MAX_LISTED as u64 + 10) {
            d += TS + 1_000;
            p.tick(k, d, TS, None);
        }
        assert_eq!(p.count, MAX_LISTED as u64 + 9);
        assert_eq!(p.listed.len(), MAX_LISTED);
        assert_eq!(p.total_ns, p.count * 1_000);
    }

    #[test]
    fn the_steal_ring_keeps_its_size() {
        let mut s = StealLog::default();
        for i in 0..(STEAL_SAMPLES as u64 * 2) {
            s.force(i * STEAL_EVERY_NS + 1, i);
        }
        assert_eq!(s.samples.len(), STEAL_SAMPLES);
        let n = STEAL_SAMPLES as u64 * 2;
        let to = (n - 1) * STEAL_EVERY_NS + 1;
        assert_eq!(
            s.between(to - STEAL_EVERY_NS, to),
            Some(s.ms_per_jiffy),
            "the newest samples"
        );
        assert_eq!(s.between(1, 2), None, "overwritten");
    }
}
