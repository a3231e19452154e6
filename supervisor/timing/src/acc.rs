//! The timing accumulator: what the supervisor saw of each tick ([`Seen`]) into histograms,\nlogs and the per-tick record ([`TimingAcc`]).

use super::*;
use deltaloop_config::RemoteSide;

/// Ticks held back by [`TimingAcc`] at most while it cannot yet tell whether they belong to the
/// loop (after the last telemetry so far) or to its end.
const PENDING_MAX: usize = 4096;

/// One tick as the supervisor saw it: each message, if it saw it.
#[derive(Clone, Copy, Debug, Default)]
pub struct Seen {
    pub k: u64,
    pub state: Option<StateMsg>,
    pub torque: Option<TorqueMsg>,
    pub tel: Option<TelemetryMsg>,
}

/// The interval logs of a run's distributions, `<prefix><name>.hlog`: one interval per second of
/// run time (tick k is at k·Ts), created at the first tick (their base time is tick 0's).
struct Hlogs {
    dir: PathBuf,
    prefix: String,
    /// In the order of [`Timing::dists`].
    writers: Option<Vec<HlogWriter>>,
}

impl Hlogs {
    /// The writers, created at the first call: tick `k`, whose deadline (CLOCK_MONOTONIC, ns) is
    /// `deadline_ns` if known, dates the base time.
    fn writers(
        &mut self,
        t: &Timing,
        k: u64,
        deadline_ns: Option<u64>,
    ) -> Result<&mut [HlogWriter]> {
        if self.writers.is_none() {
            let base = deadline_ns.map_or_else(std::time::SystemTime::now, hlog::system_time_of)
                - Duration::from_nanos(k.saturating_mul(t.ts_ns));
            let mk = |d: &Dist| {
                HlogWriter::create(
                    &self.dir.join(format!("{}{}.hlog", self.prefix, d.name)),
                    &format!(
                        "deltaloop {}{}: {}; values in ns; interval = 1 s of run time (tick k at k*Ts)",
                        self.prefix, d.name, d.what
                    ),
                    base,
                    Duration::from_secs(1),
                    &d.hist,
                )
            };
            self.writers = Some(t.dists().into_iter().map(mk).collect::<Result<_>>()?);
        }
        Ok(self.writers.as_mut().expect("just created"))
    }
}

/// [`Timing`] built one tick at a time, in tick order, in fixed memory. A run stopped early (fault,
/// interrupt) only covers the ticks it reached: the ticks after the last telemetry of the loop are
/// held back until another telemetry shows the loop went on, and left out at the end.
pub struct TimingAcc {
    t: Timing,
    /// N: the run's last tick.
    n: u64,
    ts_ns: u64,
    realtime: bool,
    prev_wake: Option<u64>,
    /// Ticks after the last loop telemetry so far.
    pending: Vec<Seen>,
    /// One past the last tick with loop telemetry.
    reached: u64,
    /// The last tick counted.
    last: Option<u64>,
    hlogs: Option<Hlogs>,
    /// The host's steal, sampled while the loop runs (realtime process runs).
    steal: Option<StealLog>,
    /// `--explain`: the missed and late ticks, to a file.
    misses: Option<crate::explain::MissLog>,
}

impl TimingAcc {
    /// Which process of the run is across the link, if one is.
    pub fn across(&self) -> Option<RemoteSide> {
        self.t.link
    }

    /// For ticks 0..=`ticks` at period `ts_ns` (ns); wake lateness and jitter only in realtime.
    /// `link`: which process is across the link, if one is (`link_rtt` is measured).
    pub fn new(ticks: u64, ts_ns: u64, realtime: bool, link: Option<RemoteSide>) -> Self {
        Self {
            t: Timing {
                timeline: Timeline::new(ticks, ts_ns),
                ts_ns,
                realtime,
                link,
                ..Timing::default()
            },
            n: ticks,
            ts_ns,
            realtime,
            prev_wake: None,
            pending: Vec::with_capacity(PENDING_MAX),
            reached: 0,
            last: None,
            hlogs: None,
            steal: None,
            misses: None,
        }
    }

    /// Also writes each missed or late tick's stamps to `log` (for `--explain`).
    pub fn with_miss_log(mut self, log: crate::explain::MissLog) -> Self {
        self.misses = Some(log);
        self
    }

    /// Also samples the host's steal while the loop runs ([`TimingAcc::sample_steal`]), so each
    /// pause says what the host took at the time.
    pub fn with_steal(mut self) -> Self {
        self.steal = Some(StealLog::default());
        self
    }

    /// Samples the host's steal at `now_ns` (every [`pauses::STEAL_EVERY_NS`] at most, unless
    /// `last`: the loop has ended), if asked for.
    pub fn sample_steal(&mut self, now_ns: u64, last: bool) {
        if let Some(s) = &mut self.steal {
            s.sample(now_ns, last);
        }
    }

    /// N: the run's last tick.
    pub fn last_tick(&self) -> u64 {
        self.n
    }

    /// Ts, ns.
    pub fn ts_ns(&self) -> u64 {
        self.ts_ns
    }

    /// Also writes each distribution's interval log, `<dir>/<prefix><name>.hlog`, as the ticks
    /// come (the files appear with the first tick).
    pub fn with_hlogs(mut self, dir: &Path, prefix: &str) -> Self {
        self.hlogs = Some(Hlogs {
            dir: dir.to_path_buf(),
            prefix: prefix.to_string(),
            writers: None,
        });
        self
    }

    /// Adds the next tick. Ticks of the safe stop after the loop are not part of it. Fails only
    /// if an interval log cannot be written.
    pub fn push(&mut self, s: Seen) -> Result<()> {
        let tel_flags = s.tel.map(|m| m.flags);
        if tel_flags.is_some_and(|f| f & wire::TEL_SAFE_STOP != 0) {
            return Ok(());
        }
        if tel_flags.is_none() {
            if self.pending.len() == PENDING_MAX {
                let oldest = self.pending.remove(0);
                self.commit(&oldest)?;
            }
            self.pending.push(s);
            return Ok(());
        }
        for p in std::mem::take(&mut self.pending) {
            self.commit(&p)?;
        }
        self.pending.reserve(PENDING_MAX);
        self.commit(&s)?;
        self.reached = s.k + 1;
        Ok(())
    }

    /// Counts tick k as part of the loop: its histograms, timeline bin and interval logs.
    fn commit(&mut self, seen: &Seen) -> Result<()> {
        let lat = self.tally(seen);
        let v = lat.in_order();
        let t = &mut self.t;
        for (d, v) in [
            &mut t.wake_lateness,
            &mut t.period_jitter,
            &mut t.state_to_controller,
            &mut t.compute,
            &mut t.round_trip,
            &mut t.link_rtt,
        ]
        .into_iter()
        .zip(v)
        {
            if let Some(v) = v {
                d.record(v);
            }
        }
        if let Some(w) = lat.wake_lateness
            && t.worst_wake.is_none_or(|(worst, _)| w > worst)
        {
            t.worst_wake = Some((w, seen.k));
        }
        let missed = seen.tel.is_some_and(|m| m.flags & wire::TEL_MISSED != 0);
        if let Some(b) = t.timeline.bin_mut(seen.k) {
            if let Some(w) = lat.wake_lateness {
                b.wake_lateness.add(w);
            }
            if let Some(r) = lat.round_trip {
                b.round_trip.add(r);
            }
            b.misses += u64::from(missed);
        }
        self.last = Some(seen.k);
        if let Some(log) = &mut self.misses {
            log.note(seen)?;
        }
        if let Some(h) = &mut self.hlogs {
            let deadline = seen
                .state
                .map(|s| s.t_deadline_ns)
                .or(seen.tel.map(|m| m.t_deadline_ns))
                .filter(|&d| d > 0);
            let at = seen.k.saturating_mul(self.ts_ns);
            for (w, v) in h.writers(&self.t, seen.k, deadline)?.iter_mut().zip(v) {
                match v {
                    Some(v) => w.record(at, v.max(1))?,
                    None => w.advance(at)?,
                }
            }
        }
        Ok(())
    }

    /// Counts tick k in the counters and returns its latencies (see [`TimingAcc::commit`]).
    fn tally(&mut self, seen: &Seen) -> TickLatencies {
        let mut v = TickLatencies::default();
        let t = &mut self.t;
        let (s, q, m) = (seen.state, seen.torque, seen.tel);
        t.ticks += 1;
        // A missing torque on a tick the plant marked missed was never sent (the controller
        // answered a newer state): that is a miss, not a loss.
        let missed = m.is_some_and(|m| m.flags & wire::TEL_MISSED != 0);
        t.lost[0] += u64::from(s.is_none());
        t.lost[1] += u64::from(q.is_none() && !missed);
        t.lost[2] += u64::from(m.is_none());
        if let Some(m) = m {
            if t.span_ns.0 == 0 {
                t.span_ns.0 = m.t_wake_ns;
            }
            t.span_ns.1 = m.t_wake_ns;
            if self.realtime {
                if m.t_deadline_ns > 0 {
                    t.pauses
                        .tick(seen.k, m.t_deadline_ns, self.ts_ns, self.steal.as_ref());
                }
                v.wake_lateness = Some(wake_lateness_ns(&m));
                if let Some(p) = self.prev_wake {
                    v.period_jitter = Some(m.t_wake_ns.saturating_sub(p).abs_diff(self.ts_ns));
                }
            }
            self.prev_wake = Some(m.t_wake_ns);
            if missed {
                t.misses += 1;
                t.miss_run += 1;
                t.max_consecutive_misses = t.max_consecutive_misses.max(t.miss_run);
            } else {
                t.miss_run = 0;
                v.round_trip = round_trip_ns(&m);
            }
            if m.flags & (wire::TEL_MISSED | wire::TEL_SAFE_STOP) == 0 {
                t.arrival.record(m.arrival_ns);
            }
            if let Some(across) = t.link {
                v.link_rtt = q.and_then(|q| link_rtt_ns(across, &m, s.as_ref(), &q));
            }
            t.late_dropped = t.late_dropped.max(m.late_dropped);
        } else {
            self.prev_wake = None;
        }
        // A reply whose stamp the plant replaced (it could not be true) says nothing of the
        // controller's hand-off or compute (regression: forged stamps gave compute p50 0.00 µs,
        // max 100 s).
        let replaced = m.is_some_and(|m| m.flags & wire::TEL_STAMP_REPLACED != 0);
        if let (Some(s), Some(q), false) = (s, q, replaced) {
            v.state_to_controller = Some(q.t_state_rx_ns.saturating_sub(s.t_publish_ns));
        }
        if let Some(q) = q {
            if !replaced {
                v.compute = Some(q.t_publish_ns.saturating_sub(q.t_state_rx_ns));
            }
            t.skipped += q.skipped;
        }
        v
    }

    /// The timing of ticks 0..n, n = the first tick the loop did not reach (at most N + 1); a
    /// state missing at tick n itself counts as lost too. The interval logs end with the last
    /// tick counted (a log is created, empty, if no tick was).
    pub fn finish(mut self) -> Result<Timing> {
        let n = self.reached.min(self.n + 1);
        if self.pending.iter().any(|p| p.k == n && p.state.is_none()) {
            self.t.lost[0] += 1;
        }
        if let Some(log) = self.misses.take() {
            self.t.miss_log = Some(log.finish()?);
        }
        if let Some(h) = &mut self.hlogs {
            let end = self.last.map_or(0, |k| k + 1).saturating_mul(self.ts_ns);
            let k = self.last.unwrap_or(0);
            h.writers(&self.t, k, None)?;
            for w in h.writers.take().into_iter().flatten() {
                w.finish(end)?;
            }
        }
        Ok(self.t)
    }
}
