//! The loop-timing parts of the reports: the terminal's timing table and report.md's timing and\noverrun sections.

use super::*;

/// Terminal lines with each law's loop timing (process modes).
pub fn timing_table(metrics: &[LawMetrics], timing: &[Option<TimingSummary>]) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "\ntiming (us)  {:>10} {:>10} {:>10} {:>10} {:>10} {:>8} {:>10}",
        "rtt p50", "rtt p99.9", "rtt max", "wake p99.9", "compute p50", "misses", "miss ratio"
    );
    for (m, t) in metrics.iter().zip(timing) {
        if let Some(t) = t {
            let _ = writeln!(
                s,
                "{:<12} {:>10.1} {:>10.1} {:>10.1} {:>10.1} {:>10.2} {:>8} {:>10.2e}",
                m.law,
                t.round_trip.p50_us,
                t.round_trip.p999_us,
                t.round_trip.max_us,
                t.wake_lateness.p999_us,
                t.controller_compute.p50_us,
                t.deadline_misses,
                t.miss_ratio
            );
        }
    }
    s
}

/// The `report.md` section on loop timing (process modes).
pub fn timing_markdown(
    cfg: &RunConfig,
    mode: LoopMode,
    metrics: &[LawMetrics],
    timing: &[Option<TimingSummary>],
) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "\n## Loop timing ({mode})\n");
    let _ = writeln!(
        s,
        "All times in µs from CLOCK_MONOTONIC stamps in the messages. Round trip: plant publishes the state → plant has the \
         torque. Wake lateness: plant wake − absolute deadline. Jitter: |period − Ts|. A miss: the controller sent no torque \
         for the tick within {} µs (the torque budget) of the plant publishing its state, so the plant held the last torque \
         (realtime only). Full distributions: `<law>.<name>.hgrm`.{}\n",
        cfg.loop_.torque_budget_us,
        if timing.iter().flatten().any(|t| t.link_rtt.is_some()) {
            " Link round trip (a run split over two hosts): the round trip less the time the state spent on \
             the controller's host (with the controller remote its residence there, `compute`; with the plant \
             remote from its arrival here to the reply), the link both ways with both bridges; one-way delays \
             are not measurable without synchronised clocks."
        } else {
            ""
        }
    );
    percentiles(&mut s, metrics, timing);
    counts(&mut s, metrics, timing);
    misses_by_cause(&mut s, metrics, timing);
    link_security(&mut s, metrics, timing);
    if mode == LoopMode::Realtime {
        s.push_str(&overrun_markdown(cfg, metrics, timing));
    }
    latency_figures(&mut s, mode, metrics, timing);
    s
}

/// The percentiles of every latency, one row per law and quantity.
fn percentiles(s: &mut String, metrics: &[LawMetrics], timing: &[Option<TimingSummary>]) {
    let _ = writeln!(
        s,
        "| law | quantity | p50 | p99 | p99.9 | p99.99 | max | count |\n|---|---|---|---|---|---|---|---|"
    );
    for (m, t) in metrics.iter().zip(timing) {
        let Some(t) = t else { continue };
        let link = t.link_rtt.as_ref().map(|p| ("link round trip", p));
        for (name, p) in [
            ("round trip", &t.round_trip),
            ("wake lateness", &t.wake_lateness),
            ("period jitter", &t.period_jitter),
            ("state → controller", &t.state_to_controller),
            ("controller compute", &t.controller_compute),
        ]
        .into_iter()
        .chain(link)
        {
            let _ = writeln!(
                s,
                "| `{}` | {name} | {:.1} | {:.1} | {:.1} | {:.1} | {:.1} | {} |",
                m.law, p.p50_us, p.p99_us, p.p999_us, p.p9999_us, p.max_us, p.count
            );
        }
    }
}

/// Ticks, misses, drops, losses and stolen CPU time per law.
fn counts(s: &mut String, metrics: &[LawMetrics], timing: &[Option<TimingSummary>]) {
    let _ = writeln!(
        s,
        "\n| law | ticks | loop wall time (s) | deadline misses | miss ratio | late replies dropped | states skipped by controller | samples lost by supervisor (state/torque/telemetry) | CPU time stolen by the hypervisor (ms) |\n|---|---|---|---|---|---|---|---|---|"
    );
    for (m, t) in metrics.iter().zip(timing) {
        let Some(t) = t else { continue };
        let l = &t.supervisor_lost_samples;
        let steal = t
            .cpu_steal_ms
            .iter()
            .map(|c| format!("cpu{} {:.0}", c.cpu, c.ms))
            .collect::<Vec<_>>()
            .join(", ");
        let _ = writeln!(
            s,
            "| `{}` | {} | {:.2} | {} | {:.2e} | {} | {} | {}/{}/{} | {} |",
            m.law,
            t.ticks,
            t.loop_wall_s,
            t.deadline_misses,
            t.miss_ratio,
            t.late_replies_dropped,
            t.controller_skipped_states,
            l.state,
            l.torque,
            l.telemetry,
            steal
        );
    }
    let _ = writeln!(
        s,
        "\nOn a virtual machine, stolen CPU time is time the hypervisor gave the (virtual) CPU to someone else: the loop \
         cannot run then, whatever its priority. Compare misses with it before blaming the loop."
    );
}

/// Who joined each law's link, and what it refused.
/// `--explain`: each law's missed ticks by cause, its top culprits, its late ticks, and the
/// figure of its worst missed tick.
fn misses_by_cause(s: &mut String, metrics: &[LawMetrics], timing: &[Option<TimingSummary>]) {
    use deltaloop_timing::sched::Cause;
    let rows: Vec<_> = metrics
        .iter()
        .zip(timing)
        .filter_map(|(m, t)| Some((m, t.as_ref()?, t.as_ref()?.explained.as_ref()?)))
        .collect();
    if rows.is_empty() {
        return;
    }
    let _ = writeln!(
        s,
        "\n### Misses by cause\n\nEach missed tick's cause from the kernel's scheduling record of the loop's CPUs \
         (`--explain`; one row per tick in `<law>.misses.csv`, how to read them: docs/guide/misses.md). `preempted`: \
         another thread held the CPU while the loop thread was runnable (the culprit); `irq`, `softirq`: an interrupt \
         ran; `wakeup`: the loop thread was woken late; `host`: it held the CPU and made no progress (the hypervisor); \
         `own`: its own work; `unknown`: no record covers the tick.\n"
    );
    let head: Vec<&str> = Cause::ALL.iter().map(|c| c.name()).collect();
    let _ = writeln!(s, "| law | missed | {} | top culprits |", head.join(" | "));
    let _ = writeln!(s, "|---|---:|{}---|", "---:|".repeat(head.len()));
    for (m, t, x) in &rows {
        let by: Vec<String> = Cause::ALL
            .iter()
            .map(|c| {
                x.miss_causes
                    .get(c.name())
                    .copied()
                    .unwrap_or(0)
                    .to_string()
            })
            .collect();
        let top = x.culprit_words(3, |c, n| format!("{c} ({n})"));
        let _ = writeln!(
            s,
            "| {} | {} | {} | {} |",
            m.law,
            t.deadline_misses,
            by.join(" | "),
            if top.is_empty() {
                "–".into()
            } else {
                top.join(", ")
            }
        );
    }
    for (m, _, x) in &rows {
        let late: u64 = x.late_causes.values().sum();
        let worst = if x.worst.is_some() {
            format!(" Its worst missed tick: `{}.worst-miss.svg`.", m.law)
        } else {
            String::new()
        };
        let by = x
            .late_words()
            .map_or(String::new(), |w| format!(" by cause: {w}"));
        let _ = writeln!(
            s,
            "\n`{}`: {late} late tick(s) (the plant woke a quarter period or more late){by}; the kernel logged {} events ({:.0} a second).{worst}",
            m.law, x.sched_events, x.sched_events_per_s
        );
    }
}

fn link_security(s: &mut String, metrics: &[LawMetrics], timing: &[Option<TimingSummary>]) {
    for (m, t) in metrics.iter().zip(timing) {
        if let Some(r) = t.as_ref().and_then(|t| t.link_security.as_ref()) {
            let _ = writeln!(
                s,
                "\nLink of `{}`: the far side {} joined with link key {}; refused {} connection(s) before it and {} datagram(s) during the run ({}), none of which reached the loop{}.",
                m.law,
                r.peer,
                r.key_fingerprint,
                r.refused_connections,
                r.refused_datagrams.total(),
                deltaloop_timing::link_refusals_by_host(r),
                deltaloop_timing::icmp_note(r)
            );
        }
    }
}

/// The latency figures: what they show, and each law's pair.
fn latency_figures(
    s: &mut String,
    mode: LoopMode,
    metrics: &[LawMetrics],
    timing: &[Option<TimingSummary>],
) {
    let _ = writeln!(
        s,
        "\n### Latency figures\n\nLatency by percentile, HdrHistogram style: x is the percentile on a log scale of \
         1/(1 − p) (0 %, 90 %, 99 %, … 99.999 %: each step one more nine), y the latency in µs (log scale); a line \
         ends where its count stops resolving the percentile, rising there to its max{}. Over run time: each band spans the min to the max of the \
         ticks in one bin (about one pixel column), the line is their mean{}. Files `<law>.latency.{{png,svg}}`, \
         `<law>.timeline.{{png,svg}}`; per-second HdrHistogram interval logs `<law>.<name>.hlog`.",
        if mode == LoopMode::Realtime {
            "; the dashed red line is the torque budget"
        } else {
            ""
        },
        if mode == LoopMode::Realtime {
            "; red triangles mark bins with deadline misses"
        } else {
            "; run time is simulated time k·Ts (lockstep does not keep the clock)"
        }
    );
    for (m, t) in metrics.iter().zip(timing) {
        if t.is_some() {
            let law = m.law;
            let _ = writeln!(
                s,
                "\n![`{law}` latency by percentile]({law}.latency.png)\n\n![`{law}` latency over run time]({law}.timeline.png)"
            );
        }
    }
}

/// Pauses listed per law in the report (all are in `summary.json`, up to its own limit).
const PAUSES_SHOWN: usize = 8;

/// The [`PAUSES_SHOWN`] longest pauses, in tick order (regression: the report showed the first
/// eight, so a 30 ms stall after eight sub-millisecond ones of a busy host was not in it).
fn longest_in_tick_order(
    list: &[deltaloop_timing::pauses::Pause],
) -> Vec<&deltaloop_timing::pauses::Pause> {
    let mut shown: Vec<_> = list.iter().collect();
    shown.sort_by(|a, b| b.ms.total_cmp(&a.ms));
    shown.truncate(PAUSES_SHOWN);
    shown.sort_by_key(|p| p.tick);
    shown
}

/// The realtime plant's own stalls: the policy, each law's real-time factor, its pauses of
/// simulated time and whether its record says the machine disturbed it.
fn overrun_markdown(
    cfg: &RunConfig,
    metrics: &[LawMetrics],
    timing: &[Option<TimingSummary>],
) -> String {
    let mut s = String::new();
    let policy = cfg.loop_.overrun;
    let bound_us = cfg.overrun_after_ns() as f64 * 1e-3;
    let _ = writeln!(
        s,
        "\n### The plant's own stalls\n\nOverrun policy `{policy}`: when the plant's own process woke more than {bound_us:.0} µs \
         late (the host did not run it), {}. Real-time factor: simulated time over wall time. Disturbance: what in the \
         run's record says the machine may have disturbed its timing.\n",
        match policy {
            Overrun::Stretch => {
                "simulated time paused for the stall (the backlog was not integrated; replies and arrivals \
                 kept a continuous simulated clock)"
            }
            Overrun::CatchUp => {
                "it ran the missed ticks back to back on the wall clock, each reply acting at its late arrival"
            }
            Overrun::Fault => "the run stopped with an overrun fault",
        }
    );
    let _ = writeln!(
        s,
        "| law | real-time factor | pauses | paused (ms) | disturbance |\n|---|---|---|---|---|"
    );
    for (m, t) in metrics.iter().zip(timing) {
        let Some(t) = t else { continue };
        let _ = writeln!(
            s,
            "| `{}` | {} | {} | {:.1} | {} |",
            m.law,
            t.realtime_factor.map_or("–".into(), |f| format!("{f:.4}")),
            t.pauses,
            t.paused_ms,
            t.disturbance.as_deref().unwrap_or("none")
        );
    }
    for (m, t) in metrics.iter().zip(timing) {
        let Some(t) = t.as_ref().filter(|t| t.pauses > 0) else {
            continue;
        };
        let _ = writeln!(s, "\nPauses of `{}`:\n", m.law);
        for p in longest_in_tick_order(&t.pause_list) {
            let _ = writeln!(
                s,
                "- tick {} (t = {:.4} s): {:.2} ms{}",
                p.tick,
                p.t_s,
                p.ms,
                p.host_steal_ms.map_or(String::new(), |st| format!(
                    "; the host stole {st:.0} ms of CPU around it"
                ))
            );
        }
        if t.pauses as usize > PAUSES_SHOWN {
            let _ = writeln!(
                s,
                "- … {} shorter ones (`summary.json` lists the first {})",
                t.pauses as usize - PAUSES_SHOWN,
                deltaloop_timing::pauses::MAX_LISTED
            );
        }
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;
    use deltaloop_timing::pauses::Pause;

    fn pause(tick: u64, ms: f64) -> Pause {
        Pause {
            tick,
            t_s: tick as f64 * 3e-4,
            ms,
            host_steal_ms: None,
        }
    }

    #[test]
    fn regression_the_report_shows_the_longest_pauses_not_the_first() {
        let mut list: Vec<Pause> = (0..10).map(|i| pause(100 + i, 0.4)).collect();
        list.push(pause(883, 30.3));
        list.push(pause(900, 0.2));
        let shown: Vec<u64> = longest_in_tick_order(&list)
            .iter()
            .map(|p| p.tick)
            .collect();
        assert_eq!(shown.len(), PAUSES_SHOWN);
        assert!(shown.contains(&883), "{shown:?}");
        assert!(!shown.contains(&900), "{shown:?}");
        assert!(
            shown.windows(2).all(|w| w[0] < w[1]),
            "tick order: {shown:?}"
        );
    }
}
