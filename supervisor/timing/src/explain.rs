//! `--explain`: the missed and late ticks as the loop stamped them, put beside the kernel's
//! record of the loop's CPUs ([`deltaloop_sched`]): `<law>.misses.csv`, the counts by cause in
//! the summary, and `<law>.worst-miss.svg`.

use super::*;
use deltaloop_sched::{Counts, Explained, MissKind, Window};

/// The loop's missed and late ticks with their stamps, written to a file as the ticks come (a
/// run's misses are not held in memory).
pub struct MissLog {
    path: PathBuf,
    w: csv::Writer<std::fs::File>,
    /// A tick whose plant woke this late or later is `late`, ns.
    late_ns: u64,
}

/// A tick is late when its plant woke this share of a period or more after its deadline.
pub const LATE_SHARE: f64 = 0.25;

impl MissLog {
    /// A log at `path`, for a loop of period `ts_ns`.
    pub fn create(path: &Path, ts_ns: u64) -> Result<Self> {
        Ok(Self {
            path: path.to_path_buf(),
            w: csv::Writer::from_path(path)
                .with_context(|| format!("cannot write {}", path.display()))?,
            late_ns: (ts_ns as f64 * LATE_SHARE) as u64,
        })
    }

    /// Notes tick `seen` if it was missed or late.
    pub(crate) fn note(&mut self, seen: &Seen) -> Result<()> {
        let Some(m) = seen.tel else { return Ok(()) };
        let missed = m.flags & wire::TEL_MISSED != 0;
        let late = m.t_deadline_ns > 0 && m.t_wake_ns >= m.t_deadline_ns + self.late_ns;
        let (rx, publ) = seen
            .torque
            .map_or((0, 0), |q| (q.t_state_rx_ns, q.t_publish_ns));
        let pub_state = seen.state.map_or(0, |s| s.t_publish_ns);
        for (kind, yes) in [("late", late), ("missed", missed && pub_state > 0)] {
            if yes {
                self.w
                    .write_record([
                        seen.k.to_string(),
                        kind.into(),
                        m.t_deadline_ns.to_string(),
                        m.t_wake_ns.to_string(),
                        pub_state.to_string(),
                        rx.to_string(),
                        publ.to_string(),
                    ])
                    .with_context(|| format!("cannot write {}", self.path.display()))?;
            }
        }
        Ok(())
    }

    /// The log's file, complete.
    pub fn finish(mut self) -> Result<PathBuf> {
        self.w
            .flush()
            .with_context(|| format!("cannot write {}", self.path.display()))?;
        Ok(self.path)
    }
}

/// The loop's threads: pid and CPU of the plant and of the controller (on this host).
#[derive(Clone, Copy, Debug)]
pub struct LoopThreads {
    pub plant: (i32, usize),
    pub controller: Option<(i32, usize)>,
}

/// The windows of a [`MissLog`] file, in start order. `budget_ns`: the torque budget.
fn windows(
    log: &Path,
    threads: LoopThreads,
    budget_ns: u64,
) -> Result<impl Iterator<Item = Window>> {
    let r = csv::ReaderBuilder::new()
        .has_headers(false)
        .from_path(log)
        .with_context(|| format!("cannot read {}", log.display()))?;
    Ok(r.into_records()
        .filter_map(Result::ok)
        .filter_map(move |r| {
            let n = |i: usize| r.get(i).and_then(|v| v.parse::<u64>().ok());
            let (k, deadline, wake, pub_state, rx, publ) =
                (n(0)?, n(2)?, n(3)?, n(4)?, n(5)?, n(6)?);
            Some(if r.get(1)? == "late" {
                Window {
                    k,
                    kind: MissKind::Late,
                    cpu: threads.plant.1,
                    pid: threads.plant.0,
                    from_ns: deadline,
                    to_ns: wake,
                    work: None,
                    link: None,
                }
            } else {
                // A controller across the link: its CPU is not recorded here; the window is the
                // plant's (what it waited for), and the stamps say which leg was late.
                let (pid, cpu) = threads.controller.unwrap_or(threads.plant);
                let to_ns = pub_state + budget_ns;
                Window {
                    k,
                    kind: MissKind::Missed,
                    cpu,
                    pid,
                    from_ns: pub_state,
                    to_ns,
                    work: (threads.controller.is_some() && rx > 0 && publ >= rx)
                        .then_some((rx, publ)),
                    link: threads
                        .controller
                        .is_none()
                        .then(|| leg(pub_state, to_ns, rx, publ)),
                }
            })
        }))
}

/// Which leg of the link a missed tick's stamps blame: the state arrived after the budget ended
/// (`state leg`), the reply was sent within it and came late (`reply leg`), the controller took
/// the state in time and answered late (`far host`), or nothing came back (`no reply`). The
/// controller's stamps are read on the plant's clock: on one machine (`bench net`) they are;
/// across two hosts the legs are as good as the hosts' clocks agree.
fn leg(pub_state: u64, to_ns: u64, rx: u64, publ: u64) -> &'static str {
    match (rx, publ) {
        (0, _) | (_, 0) => "no reply",
        (rx, _) if rx > to_ns => "state leg",
        (_, p) if p <= to_ns && p >= pub_state => "reply leg",
        _ => "far host",
    }
}

/// Explains a law's run from the kernel's record `record` (what a recorder counted in
/// `counts`) and its [`MissLog`] `log`: writes `<dir>/<law>.misses.csv` and, if a tick was
/// missed, `<dir>/<law>.worst-miss.svg`; removes both inputs.
pub fn explain(
    dir: &Path,
    law: &str,
    (record, counts): (&Path, Counts),
    log: &Path,
    threads: LoopThreads,
    budget_ns: u64,
) -> Result<Explained> {
    let pids: Vec<i32> = std::iter::once(threads.plant.0)
        .chain(threads.controller.map(|c| c.0))
        .collect();
    let x = deltaloop_sched::analyse(
        record,
        counts,
        &pids,
        windows(log, threads, budget_ns)?,
        &dir.join(format!("{law}.misses.csv")),
    )?;
    if let Some(w) = &x.worst {
        worst_figure(dir, law, record, threads, w, &pids)?;
    }
    let _ = std::fs::remove_file(record);
    let _ = std::fs::remove_file(log);
    Ok(x)
}

/// `<law>.worst-miss.svg`: the loop's CPUs from 1 ms before the worst missed tick's state to
/// 1 ms after its budget ended.
fn worst_figure(
    dir: &Path,
    law: &str,
    record: &Path,
    threads: LoopThreads,
    w: &deltaloop_sched::Verdict,
    pids: &[i32],
) -> Result<()> {
    let mut cpus = vec![threads.plant.1];
    if let Some(c) = threads.controller
        && c.1 != threads.plant.1
    {
        cpus.push(c.1);
    }
    cpus.sort_unstable();
    let (t0, t1) = (w.from_ns.saturating_sub(1_000_000), w.to_ns + 1_000_000);
    let events = deltaloop_sched::events(record)
        .with_context(|| format!("cannot read {}", record.display()))?;
    let segs = deltaloop_sched::timeline::segments(events, &cpus, pids, (t0, t1));
    let us = |t: u64| (t as f64 - w.from_ns as f64) * 1e-3;
    let bars: Vec<deltaloop_plot::lanes::Bar> = segs
        .iter()
        .map(|s| deltaloop_plot::lanes::Bar {
            cpu: s.cpu,
            from_us: us(s.from_ns),
            to_us: us(s.to_ns),
            label: &s.label,
            is_loop: s.is_loop,
        })
        .collect();
    let who = w
        .culprit
        .as_ref()
        .map(|c| format!(" by {} (pid {}, {})", c.comm, c.pid, c.policy()))
        .or(w.source.as_ref().map(|s| format!(" ({s})")))
        .unwrap_or_default();
    let title = format!(
        "{law}: worst missed tick {} — {}{who}, {:.0} µs of the budget",
        w.k,
        w.cause.name(),
        w.lost_us
    );
    deltaloop_plot::lanes::cpu_lanes(
        &dir.join(format!("{law}.worst-miss.svg")),
        &title,
        &cpus,
        (us(t0), us(t1)),
        &bars,
        &[(0.0, "state published"), (us(w.to_ns), "budget ends")],
    )
}
