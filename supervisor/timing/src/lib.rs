//! A run's loop timing from the stamps in its messages (CLOCK_MONOTONIC ns): the round trip, the
//! wake-up lateness and, across two hosts, the link's round trip, in HdrHistograms ([`Timing`]);
//! the per-tick timing file ([`TimingCsv`]), the interval logs ([`hlog`]), the pauses of the
//! simulator's own process ([`pauses`]), steal time, and a running account for live views
//! ([`live`]). Computed off the loop's path, by a run's observers and after it; the report and
//! the runner stand on it.

mod acc;
pub mod explain;
pub mod hlog;
pub mod live;
pub mod pauses;
mod steal;
mod tick_csv;
pub mod timeline;

pub use acc::{Seen, TimingAcc};
pub use deltaloop_sched as sched;
pub use steal::{StealMs, steal_jiffies, steal_ms_between};
pub use tick_csv::{TIMING_COLUMNS, TimingCsv, timing_cells};

use crate::timeline::Timeline;
use anyhow::{Context, Result};
use deltaloop_config::RemoteSide;
use deltaloop_link_setup::LinkReport;
pub use deltaloop_study::latency_histogram;
use deltaloop_wire::{self as wire, StateMsg, TelemetryMsg, TorqueMsg};
use hdrhistogram::Histogram;
use hlog::HlogWriter;
use pauses::{Pause, Pauses, StealLog};
use serde::Serialize;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::Duration;

/// One named latency distribution, ns.
#[derive(Debug, Clone)]
pub struct Dist {
    pub name: &'static str,
    pub what: &'static str,
    pub hist: Histogram<u64>,
}

impl Dist {
    fn new(name: &'static str, what: &'static str) -> Self {
        // 1 ns .. 100 s, 3 significant digits.
        Self {
            name,
            what,
            hist: latency_histogram(),
        }
    }

    fn record(&mut self, ns: u64) {
        self.hist.saturating_record(ns.max(1));
    }
}

/// Percentiles of one distribution, µs.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct Percentiles {
    pub count: u64,
    pub p50_us: f64,
    pub p99_us: f64,
    pub p999_us: f64,
    pub p9999_us: f64,
    pub max_us: f64,
}

/// Counters and distributions of one run of one law.
#[derive(Debug, Clone)]
pub struct Timing {
    /// Plant wake − deadline (realtime only).
    pub wake_lateness: Dist,
    /// |wake_k − wake_{k−1} − Ts| (realtime only).
    pub period_jitter: Dist,
    /// State published (plant) → taken (controller).
    pub state_to_controller: Dist,
    /// Controller: state taken → torque published.
    pub compute: Dist,
    /// Plant: state published → torque received.
    pub round_trip: Dist,
    /// A run split over two hosts: the round trip less the time on the controller's host
    /// ([`link_rtt_ns`]), i.e. the link both ways (network, both bridges, the hand-offs on the
    /// plant's host); recorded only when [`Timing::link`]. One-way delays are not measurable
    /// without synchronised clocks.
    pub link_rtt: Dist,
    /// Which process of the run was across the link, if one was: `link_rtt` is measured and
    /// written.
    pub link: Option<RemoteSide>,
    /// Across the link: who joined, with which key (its fingerprint), what the link refused.
    pub link_report: Option<LinkReport>,
    /// A_k − t_k of every applied command (when it took effect after its tick), ns; not written
    /// to a file of its own (it is `timing.csv`'s `arrival_ns`).
    pub arrival: Dist,
    /// Ticks that got a command (0..=N).
    pub ticks: u64,
    /// The plant's latest wake-up (realtime): lateness (ns) and its tick.
    pub worst_wake: Option<(u64, u64)>,
    /// The plant's pauses of simulated time for its own stalls (realtime, `overrun = "stretch"`).
    pub pauses: Pauses,
    /// Ticks whose torque was not applied (realtime): the controller sent none for the tick within
    /// the torque budget, counted from the state's publication (not from the tick's deadline).
    pub misses: u64,
    /// The longest run of consecutive missed ticks (realtime): how long the drives held one
    /// torque at most, in ticks.
    pub max_consecutive_misses: u64,
    /// The run of missed ticks that ends at the last tick counted.
    miss_run: u64,
    /// Late replies the plant dropped (realtime; the telemetry's running count). The plant judges
    /// a reply by the controller's send time, not by when the reply arrives or by its tick number
    /// alone: a reply for the current tick sent after the torque budget (state publication +
    /// budget), or any reply for an earlier tick, is late. Replies for later ticks are ignored.
    pub late_dropped: u64,
    /// States the controller skipped to answer the newest.
    pub skipped: u64,
    /// Samples the supervisor did not receive (its queue overflowed): state, torque, telemetry.
    pub lost: [u64; 3],
    /// Plant wake times of the first and last tick with telemetry, ns (the loop's span).
    pub span_ns: (u64, u64),
    /// Hypervisor steal per CPU during the run.
    pub steal: Vec<StealMs>,
    /// Peak memory of the three processes.
    pub peak_rss: PeakRss,
    /// Round trip, wake lateness and misses over run time, binned (for the timeline figure).
    pub timeline: Timeline,
    /// Ts, ns.
    pub ts_ns: u64,
    /// The run was realtime (wake lateness, jitter and misses are measured).
    pub realtime: bool,
    /// `--explain`: the missed and late ticks by cause, from the kernel's record.
    pub explained: Option<deltaloop_sched::Explained>,
    /// `--explain`: the file of the missed and late ticks ([`explain::MissLog`]), until they
    /// are explained.
    pub miss_log: Option<PathBuf>,
}

/// Peak resident set size (VmHWM) of each process of a run, MiB: the supervisor's over its whole
/// life so far, each child's over its life (None: it did not exit by itself). Shared memory the
/// process touched counts.
#[derive(Debug, Clone, Default, Serialize, PartialEq)]
pub struct PeakRss {
    pub supervisor: f64,
    pub plant: Option<f64>,
    pub controller: Option<f64>,
}

impl PeakRss {
    /// From KiB, as getrusage and wait4 give it.
    pub fn from_kib(supervisor: u64, plant: Option<u64>, controller: Option<u64>) -> Self {
        let mib = |k: u64| (k as f64 / 1024.0 * 10.0).round() / 10.0;
        Self {
            supervisor: mib(supervisor),
            plant: plant.map(mib),
            controller: controller.map(mib),
        }
    }
}

/// One tick's latencies, ns (None: not measured at this tick).
#[derive(Clone, Copy, Debug, Default)]
struct TickLatencies {
    wake_lateness: Option<u64>,
    period_jitter: Option<u64>,
    state_to_controller: Option<u64>,
    compute: Option<u64>,
    round_trip: Option<u64>,
    link_rtt: Option<u64>,
}

impl TickLatencies {
    /// In the order of `Timing::dists` and of the interval logs (`link_rtt` last: only runs
    /// across the link have its log).
    fn in_order(self) -> [Option<u64>; 6] {
        [
            self.wake_lateness,
            self.period_jitter,
            self.state_to_controller,
            self.compute,
            self.round_trip,
            self.link_rtt,
        ]
    }
}

/// `summary.json` timing block.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct TimingSummary {
    pub ticks: u64,
    /// Ticks without an applied torque (see [`Timing::misses`]: the budget runs from the state's
    /// publication).
    pub deadline_misses: u64,
    /// The longest run of consecutive missed ticks.
    pub max_consecutive_misses: u64,
    pub miss_ratio: f64,
    /// Replies dropped as late: for this tick but sent after the budget, or for an earlier tick
    /// (see [`Timing::late_dropped`]).
    pub late_replies_dropped: u64,
    pub controller_skipped_states: u64,
    pub supervisor_lost_samples: LostSamples,
    /// Wall time of the loop (first to last tick), s.
    pub loop_wall_s: f64,
    /// Time the hypervisor stole from each CPU during the run, ms (VMs; 0 on bare metal).
    pub cpu_steal_ms: Vec<StealMs>,
    /// Peak memory of each process, MiB.
    pub peak_rss_mib: PeakRss,
    pub wake_lateness: Percentiles,
    /// The tick of the plant's latest wake-up (`wake_lateness.max_us`), realtime.
    pub wake_lateness_max_tick: Option<u64>,
    /// Simulated time over wall time (realtime): 1 when the plant kept to the wall clock, below
    /// 1 when it paused simulated time for its own stalls (`overrun = "stretch"`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub realtime_factor: Option<f64>,
    /// The plant's pauses of simulated time for its own stalls: how many, and their total, ms.
    pub pauses: u64,
    pub paused_ms: f64,
    /// The first [`pauses::MAX_LISTED`] pauses: tick, length, the host's steal around each.
    pub pause_list: Vec<Pause>,
    /// Why the machine may have disturbed this run's timing (realtime; None: nothing in its
    /// record says so): the plant paused or woke a tick or more late, or misses beyond
    /// [`MAX_MISS_SHARE`] of the ticks or a burst of [`MAX_MISS_BURST`]; the host's steal is
    /// added for context. Outcomes that depend on timing are judged only on runs without it.
    pub disturbance: Option<String>,
    pub period_jitter: Percentiles,
    pub state_to_controller: Percentiles,
    pub controller_compute: Percentiles,
    pub round_trip: Percentiles,
    /// A run split over two hosts only (absent otherwise): the link's round trip (see
    /// [`Timing::link_rtt`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub link_rtt: Option<Percentiles>,
    /// A run split over two hosts only: the far side's address, the link key's fingerprint (never
    /// the key), the connections refused before it joined and the datagrams refused by reason
    /// (malformed, other_run, forged, replayed; `refused_datagrams` both hosts together, `near`
    /// and `far` each host's own), none of which reached the loop.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub link_security: Option<LinkReport>,
    /// `--explain` only: `miss_causes` {cause: missed ticks}, `miss_culprits` {command name:
    /// missed ticks}, `late_causes`, and the kernel's events read (`sched_events`, per second).
    #[serde(flatten, skip_serializing_if = "Option::is_none")]
    pub explained: Option<deltaloop_sched::Explained>,
}

/// One line if the link refused anything during a run (connections before the far side
/// joined, datagrams during the run on either host): what, where, and that none of it reached
/// the loop.
pub fn link_refusals_note(r: Option<&LinkReport>) -> Option<String> {
    let r = r?;
    if r.refused_connections == 0 && r.refused_datagrams.total() == 0 && r.icmp_errors == 0 {
        return None;
    }
    Some(format!(
        "the link refused {} connection(s) before {} joined and {} datagram(s) during the run ({}); none reached the loop{}",
        r.refused_connections,
        r.peer,
        r.refused_datagrams.total(),
        link_refusals_by_host(r),
        icmp_note(r)
    ))
}

/// `; N ICMP error report(s) …` when the link's UDP sockets had any (an ICMP port, host or
/// network unreachable quoting their addresses, which anyone who knows them can send), else
/// empty.
pub fn icmp_note(r: &LinkReport) -> String {
    if r.icmp_errors == 0 {
        return String::new();
    }
    let far = r.far.map_or("?".into(), |f| f.icmp_errors.to_string());
    format!(
        "; {} ICMP error report(s) (port, host or network unreachable) on the link's UDP sockets (here {}, on the far host {far}), each datagram they held back sent again",
        r.icmp_errors, r.near.icmp_errors
    )
}

/// The datagrams each host refused, by reason: `here: malformed 0, …; on the far host: …`.
pub fn link_refusals_by_host(r: &LinkReport) -> String {
    let by_reason = |d: &deltaloop_link_setup::RefusedCounts| {
        format!(
            "malformed {}, other run {}, forged {}, replayed {}",
            d.malformed, d.other_run, d.forged, d.replayed
        )
    };
    let far = r
        .far
        .map_or("did not report (the link went down first)".into(), |f| {
            by_reason(&f.refused_datagrams)
        });
    format!(
        "here: {}; on the far host: {far}",
        by_reason(&r.near.refused_datagrams)
    )
}

/// The share of missed ticks above which a realtime run counts as disturbed by the machine (see
/// [`TimingSummary::disturbance`]).
pub const MAX_MISS_SHARE: f64 = 0.02;

/// The burst of consecutive missed ticks from which a realtime run counts as disturbed: one
/// torque held for 1.5 ms or more can cost more tracking than a whole delay under study (bursts
/// of 7 to 11 cost `tdc` +16 % to +128 % on S1; bursts of 3 left it within 1 %,
/// docs/guide/delay-study.md).
pub const MAX_MISS_BURST: u64 = 5;

/// Samples the supervisor lost per stream.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct LostSamples {
    pub state: u64,
    pub torque: u64,
    pub telemetry: u64,
}

impl Default for Timing {
    fn default() -> Self {
        Self {
            wake_lateness: Dist::new(
                "wake_lateness",
                "plant wake time minus its absolute deadline",
            ),
            period_jitter: Dist::new("period_jitter", "|wake(k) - wake(k-1) - Ts|"),
            state_to_controller: Dist::new(
                "state_to_controller",
                "state published by the plant -> taken by the controller",
            ),
            compute: Dist::new(
                "controller_compute",
                "controller: state taken -> torque published",
            ),
            round_trip: Dist::new("round_trip", "plant: state published -> torque received"),
            link_rtt: Dist::new(
                "link_rtt",
                "across the link: round trip less the time on the controller's host (the link both ways)",
            ),
            link: None,
            link_report: None,
            arrival: Dist::new("arrival", "A_k - t_k: when an applied command took effect"),
            ticks: 0,
            worst_wake: None,
            pauses: Pauses::default(),
            misses: 0,
            max_consecutive_misses: 0,
            miss_run: 0,
            late_dropped: 0,
            skipped: 0,
            lost: [0; 3],
            span_ns: (0, 0),
            steal: Vec::new(),
            peak_rss: PeakRss::default(),
            timeline: Timeline::default(),
            ts_ns: 0,
            realtime: false,
            explained: None,
            miss_log: None,
        }
    }
}

/// Wake lateness of one tick from its telemetry, ns: plant wake − absolute deadline (0 in
/// lockstep, where the deadline is the wake). Live observers (`deltaloop top`, `soak`) use it too.
pub fn wake_lateness_ns(m: &TelemetryMsg) -> u64 {
    m.t_wake_ns.saturating_sub(m.t_deadline_ns)
}

/// Round trip of one tick from its telemetry, ns: state published → reply received by the plant;
/// None when the tick was missed or no reply was received.
pub fn round_trip_ns(m: &TelemetryMsg) -> Option<u64> {
    (m.flags & wire::TEL_MISSED == 0 && m.t_torque_rx_ns > 0)
        .then(|| m.t_torque_rx_ns.saturating_sub(m.t_state_pub_ns))
}

/// The link's round trip of one tick of a run split over two hosts, ns: the round trip
/// ([`round_trip_ns`], on the plant's clock) less the time the state spent on the controller's
/// host. With the controller across, that residence is what the near bridge puts in the reply
/// as `t_publish_ns − t_state_rx_ns`; with the plant across, it is measured here, from the
/// state's arrival (its `t_publish_ns` on this host's clock) to the reply. None where the round
/// trip is.
pub fn link_rtt_ns(
    across: RemoteSide,
    m: &TelemetryMsg,
    s: Option<&StateMsg>,
    q: &TorqueMsg,
) -> Option<u64> {
    // With the plant across, the state's arrival here: its publication by the near bridge, or
    // (the direct path, where the controller takes it from the socket and the bridge files the
    // record's copy later) the controller's take, whichever came first.
    let from = match across {
        RemoteSide::Controller => q.t_state_rx_ns,
        RemoteSide::Plant => s?.t_publish_ns.min(q.t_state_rx_ns.max(1)),
    };
    let residence = q.t_publish_ns.saturating_sub(from);
    round_trip_ns(m).map(|rt| rt.saturating_sub(residence))
}

impl Timing {
    /// Loop cycles per second over the observed span (0 if fewer than two ticks).
    pub fn cycle_hz(&self) -> f64 {
        let (a, b) = self.span_ns;
        let cycles = self.ticks.saturating_sub(1) as f64;
        if b > a {
            cycles / ((b - a) as f64 * 1e-9)
        } else {
            0.0
        }
    }

    /// The distributions, in the order of the `.hgrm` and `.hlog` files: five, and `link_rtt`
    /// for a run across the link.
    pub fn dists(&self) -> Vec<&Dist> {
        let mut v = vec![
            &self.wake_lateness,
            &self.period_jitter,
            &self.state_to_controller,
            &self.compute,
            &self.round_trip,
        ];
        if self.link.is_some() {
            v.push(&self.link_rtt);
        }
        v
    }

    /// Percentiles and counters for `summary.json`.
    pub fn summary(&self) -> TimingSummary {
        let p = |d: &Dist| percentiles(&d.hist);
        TimingSummary {
            ticks: self.ticks,
            deadline_misses: self.misses,
            max_consecutive_misses: self.max_consecutive_misses,
            miss_ratio: self.misses as f64 / self.ticks.max(1) as f64,
            late_replies_dropped: self.late_dropped,
            controller_skipped_states: self.skipped,
            supervisor_lost_samples: LostSamples {
                state: self.lost[0],
                torque: self.lost[1],
                telemetry: self.lost[2],
            },
            loop_wall_s: self.span_ns.1.saturating_sub(self.span_ns.0) as f64 * 1e-9,
            cpu_steal_ms: self.steal.clone(),
            peak_rss_mib: self.peak_rss.clone(),
            wake_lateness: p(&self.wake_lateness),
            wake_lateness_max_tick: self.worst_wake.map(|(_, k)| k),
            realtime_factor: if self.realtime {
                self.pauses.realtime_factor(self.ts_ns)
            } else {
                None
            },
            pauses: self.pauses.count,
            paused_ms: self.pauses.total_ns as f64 * 1e-6,
            pause_list: self.pauses.listed.clone(),
            disturbance: self.disturbance(),
            period_jitter: p(&self.period_jitter),
            state_to_controller: p(&self.state_to_controller),
            controller_compute: p(&self.compute),
            round_trip: p(&self.round_trip),
            link_rtt: self.link.map(|_| p(&self.link_rtt)),
            link_security: self.link_report.clone(),
            explained: self.explained.clone(),
        }
    }

    /// Why the machine may have disturbed this run (see [`TimingSummary::disturbance`]); None for
    /// a run that is not realtime or whose record shows nothing.
    pub fn disturbance(&self) -> Option<String> {
        if !self.realtime {
            return None;
        }
        let mut why = Vec::new();
        if let Some((ns, k)) = self.pauses.longest {
            why.push(format!(
                "the plant's own process stalled: simulated time paused {} time(s), {:.1} ms in all (longest {:.1} ms at tick {k})",
                self.pauses.count,
                self.pauses.total_ns as f64 * 1e-6,
                ns as f64 * 1e-6
            ));
        }
        if let Some((ns, k)) = self.worst_wake.filter(|(ns, _)| *ns >= self.ts_ns) {
            why.push(format!(
                "the plant once woke {:.0} µs late (tick {k}, a tick or more)",
                ns as f64 * 1e-3
            ));
        }
        let share = self.misses as f64 / self.ticks.max(1) as f64;
        if share > MAX_MISS_SHARE {
            why.push(format!(
                "{} misses ({:.1} % of the ticks, more than {:.0} %)",
                self.misses,
                share * 100.0,
                MAX_MISS_SHARE * 100.0
            ));
        }
        if self.max_consecutive_misses >= MAX_MISS_BURST {
            why.push(format!(
                "{} ticks missed in a row ({MAX_MISS_BURST} or more)",
                self.max_consecutive_misses
            ));
        }
        if why.is_empty() {
            return None;
        }
        let stolen: Vec<String> = self
            .steal
            .iter()
            .filter(|c| c.ms > 0.0)
            .map(|c| format!("{:.0} ms of CPU {}", c.ms, c.cpu))
            .collect();
        if !stolen.is_empty() {
            why.push(format!("the host took {}", stolen.join(" and ")));
        }
        if let Some(causes) = self.explained.as_ref().and_then(|x| x.words()) {
            why.push(format!("misses by cause: {causes}"));
        }
        Some(why.join("; "))
    }

    /// If the plant once woke ten ticks or more late (realtime), what that means for the run: the
    /// loop ran without control that long, whatever froze it (on a VM, usually the host: see
    /// `cpu_steal_ms`). A run that diverged or faulted just after such a freeze fell to the
    /// machine, not to the law.
    pub fn freeze_note(&self) -> Option<String> {
        let (ns, k) = self.worst_wake?;
        if self.ts_ns == 0 || ns < 10 * self.ts_ns {
            return None;
        }
        let stolen: Vec<String> = self
            .steal
            .iter()
            .map(|c| format!("{:.0} ms of CPU {}", c.ms, c.cpu))
            .collect();
        Some(format!(
            "the plant once woke {:.1} ms late (tick {k}, t = {:.3} s): the loop ran without control for about {} ticks{}",
            ns as f64 * 1e-6,
            k as f64 * self.ts_ns as f64 * 1e-9,
            ns / self.ts_ns,
            if stolen.is_empty() {
                String::new()
            } else {
                format!("; the host took {} during the run", stolen.join(" and "))
            }
        ))
    }

    /// Writes one `<prefix><name>.hgrm` percentile file per distribution into `dir`.
    pub fn write_hgrm(&self, dir: &Path, prefix: &str) -> Result<()> {
        for d in self.dists() {
            let path = dir.join(format!("{prefix}{}.hgrm", d.name));
            std::fs::write(&path, hgrm(&d.hist, d.what))
                .with_context(|| format!("cannot write {}", path.display()))?;
        }
        Ok(())
    }
}

/// p50/p99/p99.9/p99.99/max of a histogram of ns, in µs (zeros for an empty histogram).
pub fn percentiles(h: &Histogram<u64>) -> Percentiles {
    let q = |p: f64| {
        if h.is_empty() {
            0.0
        } else {
            h.value_at_quantile(p) as f64 / 1e3
        }
    };
    Percentiles {
        count: h.len(),
        p50_us: q(0.5),
        p99_us: q(0.99),
        p999_us: q(0.999),
        p9999_us: q(0.9999),
        max_us: if h.is_empty() {
            0.0
        } else {
            h.max() as f64 / 1e3
        },
    }
}

/// The standard HdrHistogram percentile-distribution text (values in µs), as written by
/// `outputPercentileDistribution` and read by the HdrHistogram plotter.
pub fn hgrm(h: &Histogram<u64>, what: &str) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "# {what}; values in microseconds");
    let _ = writeln!(
        s,
        "{:>12} {:>14} {:>10} {:>14}\n",
        "Value", "Percentile", "TotalCount", "1/(1-Percentile)"
    );
    if !h.is_empty() {
        // TotalCount is the count at or below the row's value, as Java's writer has it.
        let mut total = 0u64;
        for v in h.iter_quantiles(5) {
            total += v.count_since_last_iteration();
            let pct = v.quantile_iterated_to();
            let inv = if pct < 1.0 {
                format!("{:>14.2}", 1.0 / (1.0 - pct))
            } else {
                format!("{:>14}", "inf")
            };
            let _ = writeln!(
                s,
                "{:>12.3} {:>14.12} {:>10} {inv}",
                v.value_iterated_to() as f64 / 1e3,
                pct,
                total
            );
        }
    }
    let mean = if h.is_empty() { 0.0 } else { h.mean() / 1e3 };
    let sd = if h.is_empty() { 0.0 } else { h.stdev() / 1e3 };
    let _ = writeln!(s, "#[Mean    = {mean:>12.3}, StdDeviation   = {sd:>12.3}]");
    let _ = writeln!(
        s,
        "#[Max     = {:>12.3}, Total count    = {:>12}]",
        if h.is_empty() {
            0.0
        } else {
            h.max() as f64 / 1e3
        },
        h.len()
    );
    let _ = writeln!(
        s,
        "#[Buckets = {:>12}, SubBuckets     = {:>12}]",
        h.buckets(),
        h.distinct_values()
    );
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Regression: the `.hgrm` TotalCount column counted each row's own values, where the
    /// standard (Java's `outputPercentileDistribution`) has the count up to the row's value: it
    /// rises to the total.
    #[test]
    fn regression_hgrm_total_count_is_cumulative() {
        let mut h = histogram();
        h.record_n(10_000, 50).unwrap();
        h.record_n(90_000, 50).unwrap();
        let text = hgrm(&h, "x");
        let counts: Vec<u64> = text
            .lines()
            .filter(|l| !l.starts_with('#') && !l.trim().is_empty() && !l.contains("Value"))
            .map(|l| l.split_whitespace().nth(2).unwrap().parse().unwrap())
            .collect();
        assert!(counts.windows(2).all(|w| w[0] <= w[1]), "{counts:?}");
        assert_eq!(counts.last(), Some(&100), "{text}");
    }

    fn histogram() -> Histogram<u64> {
        Histogram::new_with_bounds(1, 100_000_000_000, 3).unwrap()
    }

    /// Regression: the near bridge's link report carries counts the far side sent (any u64);
    /// adding them for the note and the report overflowed and panicked the supervisor. A report
    /// of u64::MAX counts reads, and is said, saturated.
    #[test]
    fn regression_a_link_report_of_huge_counts_does_not_overflow() {
        let max = u64::MAX;
        let counts = format!(
            r#"{{"malformed": {max}, "other_run": {max}, "forged": {max}, "replayed": 1}}"#
        );
        let json = format!(
            r#"{{"peer": "10.0.0.2:4000", "key_fingerprint": "sha256:00", "refused_connections": {max},
                "refused_datagrams": {counts}, "near": {{"refused_datagrams": {counts}}},
                "far": {{"refused_datagrams": {counts}}}}}"#
        );
        let d = tempfile::tempdir().unwrap();
        let path = d.path().join("link-r1.json");
        std::fs::write(&path, json).unwrap();
        let r = LinkReport::read(&path).expect("a link report");
        let note = link_refusals_note(Some(&r)).unwrap();
        assert!(note.contains(&format!("and {max} datagram(s)")), "{note}");
    }

    /// Tick k of a realtime loop at Ts = 0.3 ms with made-up stamps (a few µs to a few hundred
    /// µs, varying from tick to tick); every 997th tick is missed.
    /// The link's round trip subtracts the time on the controller's host: with the controller
    /// across, the far residence the reply carries (t_publish − t_state_rx); with the plant
    /// across, from the state's arrival here (its t_publish on this host) to the reply.
    #[test]
    fn link_rtt_subtracts_the_time_on_the_controllers_host() {
        let tel = TelemetryMsg {
            t_state_pub_ns: 1_000,
            t_torque_rx_ns: 101_000,
            ..TelemetryMsg::default()
        };
        let state = StateMsg {
            t_publish_ns: 50_000,
            ..StateMsg::default()
        };
        let reply = TorqueMsg {
            t_state_rx_ns: 60_000,
            t_publish_ns: 70_000,
            ..TorqueMsg::default()
        };
        // Round trip 100 µs; the far residence 10 µs; the time here 20 µs.
        assert_eq!(
            link_rtt_ns(RemoteSide::Controller, &tel, Some(&state), &reply),
            Some(90_000)
        );
        assert_eq!(
            link_rtt_ns(RemoteSide::Plant, &tel, Some(&state), &reply),
            Some(80_000)
        );
        assert_eq!(link_rtt_ns(RemoteSide::Plant, &tel, None, &reply), None);
    }

    fn tick(k: u64, ts: u64) -> Seen {
        let r = |salt: u64| (k.wrapping_mul(6364136223846793005).wrapping_add(salt) >> 33) % 50_000;
        let deadline = 1_000_000_000 + k * ts;
        let wake = deadline + 1_000 + r(1);
        let publish = wake + 500;
        let rx = publish + 2_000 + r(2);
        let sent = rx + 300 + r(3) / 10;
        let missed = k % 997 == 500;
        Seen {
            k,
            state: Some(StateMsg {
                tick: k,
                t_deadline_ns: deadline,
                t_wake_ns: wake,
                t_publish_ns: publish,
                ..StateMsg::default()
            }),
            torque: (!missed).then_some(TorqueMsg {
                tick: k,
                t_state_rx_ns: rx,
                t_publish_ns: sent,
                ..TorqueMsg::default()
            }),
            tel: Some(TelemetryMsg {
                tick: k,
                flags: if missed { wire::TEL_MISSED } else { 0 },
                t_deadline_ns: deadline,
                t_wake_ns: wake,
                t_state_pub_ns: publish,
                t_torque_rx_ns: if missed { 0 } else { sent + 700 + r(4) },
                ..TelemetryMsg::default()
            }),
        }
    }

    /// Regression: a controller that forged its stamps (0, or 100 s in the future) was reported
    /// with a compute p50 of 0.00 µs and a max of 100 s although the plant had replaced them: a
    /// tick whose stamp the plant replaced adds nothing to the controller's distributions.
    #[test]
    fn regression_compute_leaves_out_the_stamps_the_plant_replaced() {
        let ts = 300_000;
        let mut acc = TimingAcc::new(99, ts, true, None);
        for k in 0..100 {
            let mut t = tick(k, ts);
            if k % 2 == 0
                && let (Some(q), Some(m)) = (t.torque.as_mut(), t.tel.as_mut())
            {
                q.t_state_rx_ns = 0;
                q.t_publish_ns = 100_000_000_000;
                m.flags |= wire::TEL_STAMP_REPLACED;
            }
            acc.push(t).unwrap();
        }
        let t = acc.finish().unwrap();
        assert_eq!(t.compute.hist.len(), 50);
        assert_eq!(t.state_to_controller.hist.len(), 50);
        assert!(t.compute.hist.max() < 10_000, "{}", t.compute.hist.max());
    }

    /// The interval logs hold every value of the run exactly once: per quantity, the intervals
    /// add up to the whole-run histogram, one interval per second of run time (k·Ts), the last
    /// one cut at the run's end; the timeline holds the same counts and misses.
    #[test]
    fn interval_logs_add_up_to_the_whole_run() {
        for link in [false, true] {
            interval_logs_add_up(link);
        }
    }

    /// A run across the link has a sixth distribution, `link_rtt` (round trip less the far
    /// residence); a one-host run has five and no `link_rtt` in its summary.
    fn interval_logs_add_up(link: bool) {
        let dir = tempfile::tempdir().unwrap();
        let ts = 300_000;
        let n = 11_666; // 3.5 s
        let across = link.then_some(RemoteSide::Controller);
        let mut acc = TimingAcc::new(n, ts, true, across).with_hlogs(dir.path(), "tdc.");
        for k in 0..=n {
            acc.push(tick(k, ts)).unwrap();
        }
        let t = acc.finish().unwrap();
        assert_eq!(t.ticks, n + 1);
        assert_eq!(t.misses, 12);
        assert_eq!(t.summary().max_consecutive_misses, 1);
        assert_eq!(t.dists().len(), if link { 6 } else { 5 });
        assert_eq!(
            dir.path().join("tdc.link_rtt.hlog").exists(),
            link,
            "the link's log only across the link"
        );
        let s = t.summary();
        assert_eq!(s.link_rtt.is_some(), link);
        if let Some(l) = s.link_rtt {
            assert_eq!(l.count, s.round_trip.count);
            assert!(l.p50_us < s.round_trip.p50_us, "{l:?}");
        }
        for d in t.dists() {
            let log = crate::hlog::read(&dir.path().join(format!("tdc.{}.hlog", d.name))).unwrap();
            let spans: Vec<(f64, f64)> = log
                .intervals
                .iter()
                .map(|i| (i.start_s, i.length_s))
                .collect();
            assert_eq!(
                spans,
                [(0.0, 1.0), (1.0, 1.0), (2.0, 1.0), (3.0, 0.5)],
                "{}",
                d.name
            );
            let mut sum = Histogram::new_from(&d.hist);
            for i in &log.intervals {
                assert!(!i.hist.is_empty(), "{}: every second has values", d.name);
                sum.add(&i.hist).unwrap();
            }
            assert!(d.hist.len() > n - 20, "{}: {}", d.name, d.hist.len());
            assert_eq!(sum.len(), d.hist.len(), "{}", d.name);
            let counts = |h: &Histogram<u64>| {
                h.iter_recorded()
                    .map(|v| (v.value_iterated_to(), v.count_at_value()))
                    .collect::<Vec<_>>()
            };
            assert_eq!(counts(&sum), counts(&d.hist), "{}", d.name);
        }
        let bins: Vec<_> = t.timeline.bins().collect();
        let total = |f: fn(&crate::timeline::Bin) -> u64| bins.iter().map(|b| f(b.2)).sum::<u64>();
        assert_eq!(total(|b| b.round_trip.n), t.round_trip.hist.len());
        assert_eq!(total(|b| b.wake_lateness.n), t.wake_lateness.hist.len());
        assert_eq!(total(|b| b.misses), t.misses);
    }
}
