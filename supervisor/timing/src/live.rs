//! Statistics of a loop while it runs, from the messages an observer sees: ticks, misses, the
//! round-trip and wake-lateness distributions (the same quantities from the same fields as
//! [`crate`]) and the joint tracking error (as [`deltaloop_study::record::metrics`] computes it: reference
//! minus true joint angles). No I/O: `deltaloop top` and `deltaloop soak` feed it.

use crate::pauses::Pauses;
use crate::{self as timing, Percentiles};
use deltaloop_model::Vec3;
use deltaloop_wire::{self as wire, StateMsg, TelemetryMsg};
use hdrhistogram::Histogram;

/// A running account of the ticks seen so far, in fixed memory.
pub struct LiveStats {
    /// Wake lateness is recorded only in realtime (lockstep has no deadline), as the run does.
    realtime: bool,
    /// The first and the newest tick with loop telemetry seen.
    first_tick: Option<u64>,
    last_tick: Option<u64>,
    /// Telemetry messages of the loop seen.
    seen: u64,
    /// Misses so far as the plant counts them (from the start of the run, not of the observer).
    misses: u64,
    /// Ticks between the first and newest telemetry the observer did not see (its queue
    /// overflowed: it fell behind).
    gaps: u64,
    round_trip: Histogram<u64>,
    wake_lateness: Histogram<u64>,
    /// The newest tracking error e = q_d − q_true, rad, and its tick.
    err_now: Option<(u64, Vec3)>,
    err_sq: [f64; 3],
    err_n: u64,
    /// Ts, ns, when known (realtime): the plant's pauses of simulated time are read off the
    /// deadlines with it.
    ts_ns: Option<u64>,
    pauses: Pauses,
}

/// What [`LiveStats`] shows at one instant.
#[derive(Clone, Debug, PartialEq)]
pub struct Snapshot {
    /// The tick the observer started at (its percentiles and RMS cover ticks from here).
    pub since_tick: Option<u64>,
    /// Ticks the loop has run so far: the newest tick + 1.
    pub ticks: u64,
    /// Misses so far (the plant's own count, since tick 0).
    pub misses: u64,
    /// misses / ticks.
    pub miss_ratio: f64,
    /// Telemetry the observer missed (its queue overflowed).
    pub observer_gaps: u64,
    /// Round trip (state published → reply received), µs.
    pub round_trip: Percentiles,
    /// Wake lateness (plant wake − deadline), µs; realtime only.
    pub wake_lateness: Option<Percentiles>,
    /// The newest tracking error per joint, rad, and its tick.
    pub err_now: Option<(u64, [f64; 3])>,
    /// RMS tracking error per joint over the ticks seen, rad.
    pub err_rms: Option<[f64; 3]>,
    /// Simulated time over wall time since the observer started (realtime, period known).
    pub realtime_factor: Option<f64>,
    /// The plant's pauses of simulated time for its own stalls seen so far, and their total, ms.
    pub pauses: u64,
    pub paused_ms: f64,
    /// The longest pause: ms, and the tick after it.
    pub longest_pause: Option<(f64, u64)>,
}

impl LiveStats {
    /// An empty account; wake lateness only if `realtime`.
    pub fn new(realtime: bool) -> Self {
        Self {
            realtime,
            first_tick: None,
            last_tick: None,
            seen: 0,
            misses: 0,
            gaps: 0,
            round_trip: timing::latency_histogram(),
            wake_lateness: timing::latency_histogram(),
            err_now: None,
            err_sq: [0.0; 3],
            err_n: 0,
            ts_ns: None,
            pauses: Pauses::default(),
        }
    }

    /// Also counts the plant's pauses of simulated time (realtime), with the loop's period Ts, ns.
    pub fn with_period(mut self, ts_ns: u64) -> Self {
        self.ts_ns = (ts_ns > 0).then_some(ts_ns);
        self
    }

    /// Adds one telemetry message (the safe stop after a fault is not part of the loop).
    pub fn telemetry(&mut self, m: &TelemetryMsg) {
        if m.flags & wire::TEL_SAFE_STOP != 0 {
            return;
        }
        match self.last_tick {
            Some(last) if m.tick <= last => return,
            Some(last) => self.gaps += m.tick - last - 1,
            None => self.first_tick = Some(m.tick),
        }
        self.last_tick = Some(m.tick);
        self.seen += 1;
        self.misses = self.misses.max(m.misses);
        if self.realtime {
            self.wake_lateness
                .saturating_record(timing::wake_lateness_ns(m).max(1));
            if let Some(ts) = self.ts_ns.filter(|_| m.t_deadline_ns > 0) {
                self.pauses.tick(m.tick, m.t_deadline_ns, ts, None);
            }
        }
        if let Some(rt) = timing::round_trip_ns(m) {
            self.round_trip.saturating_record(rt.max(1));
        }
    }

    /// Adds one state with its reference angles q_d (rad): the tracking error of its tick.
    pub fn state(&mut self, s: &StateMsg, q_ref: Vec3) {
        let e = q_ref - Vec3::from(s.q_true);
        for i in 0..3 {
            self.err_sq[i] += e[i] * e[i];
        }
        self.err_n += 1;
        self.err_now = Some((s.tick, e));
    }

    /// The account now.
    pub fn snapshot(&self) -> Snapshot {
        let ticks = self.last_tick.map_or(0, |k| k + 1);
        let n = self.err_n as f64;
        Snapshot {
            since_tick: self.first_tick,
            ticks,
            misses: self.misses,
            miss_ratio: self.misses as f64 / ticks.max(1) as f64,
            observer_gaps: self.gaps,
            round_trip: timing::percentiles(&self.round_trip),
            wake_lateness: self
                .realtime
                .then(|| timing::percentiles(&self.wake_lateness)),
            err_now: self.err_now.map(|(k, e)| (k, e.into())),
            err_rms: (self.err_n > 0).then(|| self.err_sq.map(|s| (s / n).sqrt())),
            realtime_factor: self
                .ts_ns
                .filter(|_| self.realtime)
                .and_then(|ts| self.pauses.realtime_factor(ts)),
            pauses: self.pauses.count,
            paused_ms: self.pauses.total_ns as f64 * 1e-6,
            longest_pause: self.pauses.longest.map(|(ns, k)| (ns as f64 * 1e-6, k)),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tel(tick: u64, rt_ns: u64, late_ns: u64, misses: u64, flags: u32) -> TelemetryMsg {
        let deadline = 1_000_000 + tick * 300_000;
        TelemetryMsg {
            tick,
            flags,
            t_deadline_ns: deadline,
            t_wake_ns: deadline + late_ns,
            t_state_pub_ns: deadline + late_ns + 1_000,
            t_torque_rx_ns: if flags & wire::TEL_MISSED != 0 {
                0
            } else {
                deadline + late_ns + 1_000 + rt_ns
            },
            misses,
            ..TelemetryMsg::default()
        }
    }

    /// Percentiles are those of the round trips and wake latenesses fed in (misses have none),
    /// the plant's miss count is taken as is, and a gap in the ticks is counted, not invented.
    #[test]
    fn percentiles_misses_and_gaps_come_from_the_telemetry() {
        let mut l = LiveStats::new(true);
        for k in 0..1000u64 {
            if k == 500 || k == 501 {
                continue;
            }
            let missed = k % 100 == 99;
            let flags = if missed { wire::TEL_MISSED } else { 0 };
            l.telemetry(&tel(k, 10_000 + k * 10, 2_000, k / 100, flags));
        }
        // A repeated or older tick and the safe stop are ignored.
        l.telemetry(&tel(10, 1, 1, 0, 0));
        l.telemetry(&tel(1000, 1, 1, 0, wire::TEL_SAFE_STOP));
        let s = l.snapshot();
        assert_eq!((s.ticks, s.misses, s.observer_gaps), (1000, 9, 2));
        assert_eq!(s.since_tick, Some(0));
        assert_eq!(s.round_trip.count, 998 - 10);
        assert!(
            (s.round_trip.max_us - 19.98).abs() < 0.03,
            "{:?}",
            s.round_trip
        );
        assert!(
            (s.round_trip.p50_us - 15.0).abs() < 0.1,
            "{:?}",
            s.round_trip
        );
        let w = s.wake_lateness.unwrap();
        assert!((w.p50_us - 2.0).abs() < 0.01 && w.count == 998, "{w:?}");
        assert!((s.miss_ratio - 9e-3).abs() < 1e-12);
        // Lockstep: no deadline, no wake lateness.
        assert!(LiveStats::new(false).snapshot().wake_lateness.is_none());
        assert_eq!(s.realtime_factor, None, "no period given");
    }

    /// With the period known, a deadline later than the ticks account for is a pause of the
    /// plant's clock: counted, its longest named, and the real-time factor below 1.
    #[test]
    fn pauses_of_the_plants_clock_show_live() {
        let mut l = LiveStats::new(true).with_period(300_000);
        for k in 0..1000u64 {
            let mut m = tel(k, 10_000, 2_000, 0, 0);
            if k >= 400 {
                m.t_deadline_ns += 10_000_000;
                m.t_wake_ns += 10_000_000;
            }
            l.telemetry(&m);
        }
        let s = l.snapshot();
        assert_eq!((s.pauses, s.longest_pause), (1, Some((10.0, 400))));
        let f = s.realtime_factor.unwrap();
        assert!((f - 299.7 / 309.7).abs() < 1e-12, "{f}");
    }

    /// The tracking error is q_d − q_true per joint, its RMS over the states seen.
    #[test]
    fn tracking_error_is_reference_minus_true_angles() {
        let mut l = LiveStats::new(false);
        for (k, d) in [(0u64, 0.003), (1, -0.004)] {
            let s = StateMsg {
                tick: k,
                q_true: [1.0 + d, 2.0, 3.0],
                q: [9.0; 3],
                ..StateMsg::default()
            };
            l.state(&s, Vec3::new(1.0, 2.0, 3.0));
        }
        let s = l.snapshot();
        let (k, e) = s.err_now.unwrap();
        assert_eq!(k, 1);
        assert!((e[0] - 0.004).abs() < 1e-12 && e[1] == 0.0);
        let rms = s.err_rms.unwrap();
        assert!((rms[0] - (12.5e-6f64).sqrt()).abs() < 1e-12, "{rms:?}");
    }
}
