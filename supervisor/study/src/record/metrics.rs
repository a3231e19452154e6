//! The study's metrics (docs/controllers.md, "What the study measures"): accumulated tick by tick
//! from a run's records, its reference and the controller constants, in bounded memory.

use crate::record::sensitivity::{self, Sensitivity};
use crate::record::{FaultKind, Outcome, RunEnd, RunStatus, TickRecord};
use crate::reference::RefRow;
use deltaloop_law::{ControllerParams, Law};
use deltaloop_model::{DeltaRobot, Vec3};
use deltaloop_spectrum::Spectra;
use serde::Serialize;

/// High-frequency threshold for torque content, Hz.
pub const HF_CUTOFF_HZ: u64 = 100;

/// Per-law metrics, as written to `summary.json`. Arrays are per joint [1, 2, 3].
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct LawMetrics {
    pub law: Law,
    /// How the run ended (see [`RunStatus`]): `ok`, `diverged`, `stopped`, `lost_data`,
    /// `interrupted` or `fault`. The fields below say the same in the older, per-case form.
    pub status: RunStatus,
    /// Why, in one line, for every status but `ok` (the `reason` of the sweep's rows).
    pub reason: Option<String>,
    /// The tick the status names: where the run was interrupted, faulted or diverged, or the
    /// first tick whose data was lost; null for `ok`.
    pub status_tick: Option<u64>,
    /// Ticks after tick 0 the metrics cover (k = 0..=N); fewer if the run diverged.
    pub ticks: u64,
    /// Whether every tick 0..=N ran and was recorded.
    pub completed: bool,
    /// Ticks the supervisor lost (its queues overflowed): not in the metrics.
    pub lost_ticks: u64,
    /// Why the run ended as "lost data", if it did.
    pub lost_data: Option<String>,
    /// Ticks recorded without the plant's telemetry (their `reply` and `drives` are `unknown`).
    pub telemetry_missing: u64,
    /// Ticks whose reply from a controller on another host may have been lost on the link and
    /// could not be recovered (their `reply` and `drives` are `unknown`).
    pub replies_lost: u64,
    /// Second (and later) replies for a tick that already had one: the first is recorded.
    pub duplicate_replies: u64,
    /// Replies the controller's own transport refused before they reached the plant (a ROS 2
    /// node's commands with wrong names, lengths, non-finite, stale, from a second publisher,
    /// undecodable), and each cause's count (None: it said nothing).
    pub refused_replies: u64,
    pub refused_replies_why: Option<String>,
    /// Ticks whose applied reply carried a publish stamp outside [state published, reply
    /// received] on the plant's clock: the plant used its own receive time instead.
    pub stamps_replaced: u64,
    /// Tick at which the run diverged, if it did.
    pub diverged_at_tick: Option<u64>,
    pub diverged_reason: Option<String>,
    /// Tick at which Ctrl-C / SIGTERM stopped the run, if it did.
    pub interrupted_at_tick: Option<u64>,
    /// Tick and cause of a loop fault (a process died or stalled), if any.
    pub fault_at_tick: Option<u64>,
    pub fault: Option<String>,
    /// What kind of fault (see [`FaultKind`]), if any.
    pub fault_kind: Option<FaultKind>,
    /// RMS joint tracking error over k = 0..=N, rad.
    pub rms_rad: [f64; 3],
    /// Max |e_i| over k = 0..=N, rad.
    pub max_abs_err_rad: [f64; 3],
    /// RMS of the task-space error |FK(q_k) − x_d(t_k)|, mm.
    pub task_rms_mm: f64,
    /// Max task-space error, mm.
    pub task_max_mm: f64,
    /// Max |τ_i| of the commanded torque over k = 0..N−1, N m.
    pub max_abs_tau_nm: [f64; 3],
    /// Total variation Σ_{k=1}^{N−1} |τ_{i,k} − τ_{i,k−1}| of the commanded torque, N m.
    pub torque_tv_nm: [f64; 3],
    /// Intervals (k = 0..N−1) in which the plant clamped some joint.
    pub clamp_count: u64,
    /// Intervals in which the plant held the previous torque (missed or rejected command).
    pub held_count: u64,
    /// Commands the plant rejected (non-finite, or over the limit under `faults.torque_limit = "reject"`).
    pub rejected_count: u64,
    /// RMS of the detrended commanded torque above 100 Hz, N m.
    pub hf_torque_rms_nm: [f64; 3],
    /// Share of the detrended torque energy above 100 Hz (0..1).
    pub hf_torque_share: [f64; 3],
    /// Frequency of the largest non-DC torque spectral line, Hz (a limit cycle shows here).
    pub torque_peak_hz: [f64; 3],
    /// RMS of the TDE error Ñ_k = N̂_k − N_k over k = 0..N−1, rad/s² (null for `pid`).
    pub tde_err_rms: Option<[f64; 3]>,
    /// max_k |Ñ_k − Ñ_{k−1}|/Ts over k = 1..N−1, rad/s³ (null for `pid`).
    pub delta_n_max: Option<[f64; 3]>,
    /// 99.9th percentile (type 7) of |Ñ_k − Ñ_{k−1}|/Ts, rad/s³ (null for `pid`).
    pub delta_n_p999: Option<[f64; 3]>,
    /// The k2 that paper eq. 43 demands: δ(δ + 3k1²)/(2k1²), δ = max over joints of δ_N, rad/s³.
    pub k2_required: Option<f64>,
    /// The k2 of the constants in use, rad/s³.
    pub k2_in_use: f64,
    /// Whether k2_in_use exceeds k2_required (a sufficient condition only: reported, not enforced).
    pub eq43_holds: Option<bool>,
    /// The metrics against the run's round-off twin (see [`crate::record::sensitivity`]), when
    /// one was run (`--sensitivity`; `deltaloop paper` and sweeps by default).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub sensitivity: Option<Sensitivity>,
}

/// RMS of a series (0 for an empty one).
pub fn rms(xs: impl ExactSizeIterator<Item = f64>) -> f64 {
    let n = xs.len();
    if n == 0 {
        return 0.0;
    }
    (xs.map(|x| x * x).sum::<f64>() / n as f64).sqrt()
}

/// Percentile p ∈ [0, 1] with linear interpolation between order statistics (Hyndman–Fan type 7,
/// numpy's default). Sorts `xs` in place. NaN for an empty slice.
pub fn percentile_type7(xs: &mut [f64], p: f64) -> f64 {
    if xs.is_empty() {
        return f64::NAN;
    }
    xs.sort_by(f64::total_cmp);
    let h = (xs.len() - 1) as f64 * p;
    let lo = h.floor() as usize;
    let hi = (lo + 1).min(xs.len() - 1);
    xs[lo] + (h - lo as f64) * (xs[hi] - xs[lo])
}

/// (HF RMS in N m, HF energy share, frequency of the largest non-DC line in Hz) of a one-sided
/// energy spectrum of an n-point series at period `ts` (s).
fn spectrum_stats(energy: &[f64], n: usize, ts: f64) -> (f64, f64, f64) {
    let (mut total, mut hf, mut peak, mut peak_j) = (0.0, 0.0, 0.0, 0usize);
    for (j, &e) in energy.iter().enumerate() {
        total += e;
        if is_high_frequency(j, n, ts) {
            hf += e;
        }
        if j > 0 && e > peak {
            peak = e;
            peak_j = j;
        }
    }
    let share = if total > 0.0 { hf / total } else { 0.0 };
    (hf.sqrt() / n as f64, share, peak_j as f64 / (n as f64 * ts))
}

/// High-frequency content of a torque series sampled every `ts` s: (HF RMS in N m, HF energy
/// share, frequency of the largest non-DC line in Hz). The straight line through the first and
/// last samples is removed; a one-sided bin j is high-frequency iff j/(n·Ts) > 100 Hz, decided
/// on integers from Ts in ns.
pub fn high_frequency(tau: &[f64], ts: f64) -> (f64, f64, f64) {
    if tau.len() < 3 {
        return (0.0, 0.0, 0.0);
    }
    let energy = Spectra::new().detrended(tau);
    spectrum_stats(&energy, tau.len(), ts)
}

/// Torque series longer than this many ticks (39.3 s at Ts = 0.3 ms) are analysed in segments of
/// this length (Welch's method, rectangular window): the memory stays fixed, and the bin width
/// 1/(L·Ts) ≈ 0.025 Hz is far finer than the 100 Hz cutoff needs.
pub const CHATTER_SEGMENT: usize = 1 << 17;

/// The high-frequency content of one joint's torque, one sample at a time. Up to
/// [`CHATTER_SEGMENT`] samples it is exactly [`high_frequency`] of the whole series; beyond, the
/// mean spectrum of consecutive segments of that length, each detrended on its own (the last
/// one is the series' final L samples, overlapping its predecessor).
pub struct ChatterAcc {
    /// The last `CHATTER_SEGMENT` samples (a ring once full).
    ring: Vec<f64>,
    count: usize,
    /// Sum of the segment spectra so far, and how many.
    energy: Vec<f64>,
    segments: usize,
    spectra: Spectra,
}

impl ChatterAcc {
    /// Room for a series of at most `expected` samples (capped at one segment).
    pub fn new(expected: usize) -> Self {
        Self {
            ring: Vec::with_capacity(expected.min(CHATTER_SEGMENT)),
            count: 0,
            energy: Vec::new(),
            segments: 0,
            spectra: Spectra::new(),
        }
    }

    pub fn push(&mut self, x: f64) {
        if self.ring.len() < CHATTER_SEGMENT {
            self.ring.push(x);
        } else {
            self.ring[self.count % CHATTER_SEGMENT] = x;
        }
        self.count += 1;
        if self.count.is_multiple_of(CHATTER_SEGMENT) {
            self.add_segment();
        }
    }

    /// Adds the spectrum of the ring's samples in time order.
    fn add_segment(&mut self) {
        let head = self.count % CHATTER_SEGMENT;
        let mut seg = self.ring[head..].to_vec();
        seg.extend_from_slice(&self.ring[..head]);
        let e = self.spectra.detrended(&seg);
        if self.energy.is_empty() {
            self.energy = e;
        } else {
            self.energy.iter_mut().zip(e).for_each(|(a, b)| *a += b);
        }
        self.segments += 1;
    }

    /// (HF RMS in N m, HF energy share, peak frequency in Hz) at period `ts` (s).
    pub fn finish(mut self, ts: f64) -> (f64, f64, f64) {
        if self.count <= CHATTER_SEGMENT {
            return high_frequency(&self.ring, ts);
        }
        if !self.count.is_multiple_of(CHATTER_SEGMENT) {
            self.add_segment();
        }
        let k = self.segments as f64;
        let mean: Vec<f64> = self.energy.iter().map(|e| e / k).collect();
        spectrum_stats(&mean, CHATTER_SEGMENT, ts)
    }
}

/// The type-7 percentile p of a stream of values whose count is at most `max_count`, in memory
/// that does not grow with the stream: only the largest values the percentile can reach are kept
/// (0.1 % of `max_count` for p99.9), exactly; when even that would exceed [`TAIL_EXACT_MAX`]
/// values, an HdrHistogram at 3 significant digits answers instead.
pub struct TailPercentile {
    p: f64,
    count: u64,
    keep: usize,
    top: std::collections::BinaryHeap<std::cmp::Reverse<TotalF64>>,
    hist: Option<hdrhistogram::Histogram<u64>>,
}

/// Values kept for an exact tail percentile (2¹⁶: runs up to 65 M ticks at p99.9).
pub const TAIL_EXACT_MAX: usize = 1 << 16;

/// f64 ordered by `total_cmp` (as [`percentile_type7`] sorts).
#[derive(Clone, Copy, Debug, PartialEq)]
struct TotalF64(f64);
impl Eq for TotalF64 {}
impl PartialOrd for TotalF64 {
    fn partial_cmp(&self, o: &Self) -> Option<std::cmp::Ordering> {
        Some(self.cmp(o))
    }
}
impl Ord for TotalF64 {
    fn cmp(&self, o: &Self) -> std::cmp::Ordering {
        self.0.total_cmp(&o.0)
    }
}

impl TailPercentile {
    pub fn new(p: f64, max_count: u64) -> Self {
        // Type 7 interpolates between order statistics floor(h) and floor(h) + 1, h = (m−1)·p: at
        // most m − floor((m−1)·p) ≤ 2 + (1 − p)·m of the largest values, for any count m.
        let keep = (2.0 + ((1.0 - p) * max_count as f64).ceil()) as usize + 1;
        let exact = keep <= TAIL_EXACT_MAX;
        Self {
            p,
            count: 0,
            keep,
            top: std::collections::BinaryHeap::with_capacity(if exact { keep + 1 } else { 0 }),
            hist: (!exact).then(|| hdrhistogram::Histogram::new(3).expect("3 digits")),
        }
    }

    pub fn push(&mut self, x: f64) {
        self.count += 1;
        if let Some(h) = &mut self.hist {
            // milli-units: the histogram holds integers.
            // (An auto-resizing histogram grows to take any value: record never fails here.)
            let _ = h.record((x * 1e3).round().clamp(0.0, (u64::MAX >> 2) as f64) as u64);
            return;
        }
        self.top.push(std::cmp::Reverse(TotalF64(x)));
        if self.top.len() > self.keep {
            self.top.pop();
        }
    }

    /// The percentile (NaN for an empty stream).
    pub fn value(self) -> f64 {
        if self.count == 0 {
            return f64::NAN;
        }
        if let Some(h) = &self.hist {
            return h.value_at_quantile(self.p) as f64 / 1e3;
        }
        let mut top: Vec<f64> = self.top.into_iter().map(|r| r.0.0).collect();
        top.sort_by(f64::total_cmp);
        // Order statistic r of all m values is top[r − (m − kept)].
        let m = self.count as usize;
        let skipped = m - top.len();
        let h = (m - 1) as f64 * self.p;
        let lo = h.floor() as usize;
        let hi = (lo + 1).min(m - 1);
        let at = |r: usize| top[r.saturating_sub(skipped).min(top.len() - 1)];
        at(lo) + (h - lo as f64) * (at(hi) - at(lo))
    }
}

/// Whether one-sided bin j of an n-point FFT at period `ts` (s) lies above [`HF_CUTOFF_HZ`]:
/// j/(n·Ts) > f_c, decided on integers (j·10⁹ > f_c·n·Ts in ns) so a bin exactly at the cutoff is out.
pub fn is_high_frequency(j: usize, n: usize, ts: f64) -> bool {
    let ts_ns = (ts * 1e9).round() as u128;
    (j as u128) * 1_000_000_000 > u128::from(HF_CUTOFF_HZ) * n as u128 * ts_ns
}

/// The k2 that paper eq. 43 demands for TDE-error derivative bound δ_N and gain k1.
pub fn k2_required(delta_n: f64, k1: f64) -> f64 {
    delta_n * (delta_n + 3.0 * k1 * k1) / (2.0 * k1 * k1)
}

/// Every metric of one law's run, accumulated tick by tick in one pass (the ticks come from a
/// [`Recorder`](crate::record::Recorder) in order), in memory that does not grow with the run.
/// Sums run in tick order, so the numbers are the ones a pass over the whole trace gives.
pub struct MetricsAcc<'a> {
    robot: &'a DeltaRobot,
    params: ControllerParams,
    /// N: ticks 0..N−1 carry the torque metrics.
    n: usize,
    ts: f64,
    uses_tde: bool,
    records: u64,
    err_sq: [f64; 3],
    err_max: [f64; 3],
    task_sq: f64,
    task_max: f64,
    /// Torque metrics (ticks k < N, or the first tick).
    taus: u64,
    prev_tau: Option<(u64, Vec3)>,
    tau_max: [f64; 3],
    tv: [f64; 3],
    clamped: u64,
    held: u64,
    rejected: u64,
    chatter: [ChatterAcc; 3],
    /// TDE error Ñ: the previous entry of the Ñ sequence (None: unanswered, or a hole), count and
    /// sums of the answered ones, and the derivative statistics.
    prev_n_tilde: Option<Vec3>,
    answered: u64,
    tde_sq: [f64; 3],
    dn_max: [f64; 3],
    dn_tail: [TailPercentile; 3],
}

impl<'a> MetricsAcc<'a> {
    /// An accumulator for `law` over a run of ticks 0..=`n` at period `ts` (s).
    pub fn new(
        law: Law,
        n: usize,
        ts: f64,
        robot: &'a DeltaRobot,
        params: &ControllerParams,
    ) -> Self {
        Self {
            robot,
            params: *params,
            n,
            ts,
            uses_tde: law.uses_tde(),
            records: 0,
            err_sq: [0.0; 3],
            err_max: [0.0; 3],
            task_sq: 0.0,
            task_max: 0.0,
            taus: 0,
            prev_tau: None,
            tau_max: [0.0; 3],
            tv: [0.0; 3],
            clamped: 0,
            held: 0,
            rejected: 0,
            chatter: std::array::from_fn(|_| ChatterAcc::new(n)),
            prev_n_tilde: None,
            answered: 0,
            tde_sq: [0.0; 3],
            dn_max: [0.0; 3],
            dn_tail: std::array::from_fn(|_| TailPercentile::new(0.999, n as u64)),
        }
    }

    /// Adds tick k: its record, reference row and TDE truth N_k (rad/s²).
    pub fn push(&mut self, r: &TickRecord, row: &RefRow, n_true: Option<Vec3>) {
        // Error metrics over k = 0..=N (or up to the divergence tick).
        self.records += 1;
        for i in 0..3 {
            let e = row.joint.q[i] - r.q_true[i];
            self.err_sq[i] += e * e;
            self.err_max[i] = self.err_max[i].max(e.abs());
        }
        let task_mm = match self.robot.fk(&r.q_true) {
            Ok(x) => (x - row.task.x).norm() * 1e3,
            Err(_) => f64::NAN,
        };
        self.task_sq += task_mm * task_mm;
        self.task_max = self.task_max.max(task_mm);

        // Torque metrics over k = 0..N−1: the intervals whose command the plant applied. (With
        // lost ticks the series has holes: differences across one are left out; the spectrum
        // treats the series as evenly sampled.)
        let k = r.sample.k;
        if (k as usize) >= self.n && self.taus > 0 {
            return;
        }
        self.taus += 1;
        let consecutive = self.prev_tau.is_some_and(|(pk, _)| k == pk + 1);
        for i in 0..3 {
            self.tau_max[i] = self.tau_max[i].max(r.tau[i].abs());
            if let Some((_, p)) = self.prev_tau.filter(|_| consecutive) {
                self.tv[i] += (r.tau[i] - p[i]).abs();
            }
            self.chatter[i].push(r.tau[i]);
        }
        self.prev_tau = Some((k, r.tau));
        self.clamped += u64::from(r.clamped);
        self.held += u64::from(r.held);
        self.rejected += u64::from(r.rejected);

        // TDE error Ñ_k = N̂_k − N_k, k = 0..N−1. A tick the controller never answered, or whose
        // next tick was lost, has no Ñ: it is left out, and so are the differences spanning it.
        if self.taus > 1 && !consecutive {
            self.prev_n_tilde = None;
        }
        let n_tilde = r.out.zip(n_true).map(|(o, t)| o.n_hat - t);
        if let Some(v) = n_tilde {
            self.answered += 1;
            for i in 0..3 {
                self.tde_sq[i] += v[i] * v[i];
            }
            if let Some(p) = self.prev_n_tilde {
                for i in 0..3 {
                    let d = ((v[i] - p[i]) / self.ts).abs();
                    self.dn_max[i] = self.dn_max[i].max(d);
                    self.dn_tail[i].push(d);
                }
            }
        }
        self.prev_n_tilde = n_tilde;
    }

    /// The metrics, given how the run ended.
    pub fn finish(self, end: &RunEnd) -> LawMetrics {
        let rms_of = |sq: f64, n: u64| if n == 0 { 0.0 } else { (sq / n as f64).sqrt() };
        let ts = self.ts;
        let [c0, c1, c2] = self.chatter;
        let hf = [c0.finish(ts), c1.finish(ts), c2.finish(ts)];
        let uses_tde = self.uses_tde;
        let params = self.params;
        let tde_err_rms = uses_tde.then(|| self.tde_sq.map(|s| rms_of(s, self.answered)));
        let delta_n_max = uses_tde.then_some(self.dn_max);
        let delta_n_p999 = uses_tde.then(|| self.dn_tail.map(TailPercentile::value));
        let k2_req = delta_n_max.map(|d| k2_required(d.into_iter().fold(0.0, f64::max), params.k1));
        let lost_data = (end.outcome == Outcome::LostData).then(|| end.lost_data_text());
        let (completed, diverged_at_tick, diverged_reason) = match &end.outcome {
            Outcome::Diverged { tick, reason } => (false, Some(*tick), Some(reason.clone())),
            Outcome::Completed => (true, None, None),
            _ => (false, None, None),
        };
        let interrupted_at_tick = match end.outcome {
            Outcome::Interrupted { tick } => Some(tick),
            _ => None,
        };
        let (fault_at_tick, fault) = end.fault.clone().map(|f| (f.tick, f.cause)).unzip();
        LawMetrics {
            law: end.law,
            status: end.status(),
            reason: end.reason(),
            status_tick: end.status_tick(),
            fault_kind: end.fault.as_ref().map(|f| f.kind),
            ticks: self.records.saturating_sub(1),
            lost_ticks: end.lost_ticks,
            lost_data,
            telemetry_missing: end.no_telemetry,
            replies_lost: end.replies_lost,
            duplicate_replies: end.duplicate_replies,
            refused_replies: end.refused_replies,
            refused_replies_why: end.refused_replies_why.clone(),
            stamps_replaced: end.stamps_replaced,
            completed,
            diverged_at_tick,
            diverged_reason,
            interrupted_at_tick,
            fault_at_tick,
            fault,
            rms_rad: self.err_sq.map(|s| rms_of(s, self.records)),
            max_abs_err_rad: self.err_max,
            task_rms_mm: rms_of(self.task_sq, self.records),
            task_max_mm: self.task_max,
            max_abs_tau_nm: self.tau_max,
            torque_tv_nm: self.tv,
            clamp_count: self.clamped,
            held_count: self.held,
            rejected_count: self.rejected,
            hf_torque_rms_nm: hf.map(|h| h.0),
            hf_torque_share: hf.map(|h| h.1),
            torque_peak_hz: hf.map(|h| h.2),
            tde_err_rms,
            delta_n_max,
            delta_n_p999,
            k2_required: k2_req,
            k2_in_use: params.k2,
            eq43_holds: k2_req.map(|r| params.k2 > r),
            sensitivity: None,
        }
    }
}

impl LawMetrics {
    /// The spreads between this run's metrics and its round-off twin's.
    fn against_twin(&self, twin: &LawMetrics) -> Sensitivity {
        let run = self;
        Sensitivity {
            rms_rel: sensitivity::rel3(run.rms_rad, twin.rms_rad),
            max_err_rel: sensitivity::rel3(run.max_abs_err_rad, twin.max_abs_err_rad),
            task_rms_rel: sensitivity::rel_spread(run.task_rms_mm, twin.task_rms_mm),
            tde_rel: run
                .tde_err_rms
                .zip(twin.tde_err_rms)
                .map(|(a, b)| sensitivity::rel3(a, b)),
            twin_rms_rad: twin.rms_rad.into_iter().fold(0.0, f64::max),
            twins: 1,
            rms_rel_median: f64::NAN,
        }
    }

    /// The spreads against several twins: each the largest over them (the digits kept follow
    /// it), with the twins' count and the median RMS spread. None without a twin.
    pub fn against_twins(&self, twins: &[LawMetrics]) -> Option<Sensitivity> {
        let each: Vec<Sensitivity> = twins.iter().map(|t| self.against_twin(t)).collect();
        let worst = each
            .iter()
            .copied()
            .max_by(|a, b| a.rms_rel.total_cmp(&b.rms_rel))?;
        let max = |f: fn(&Sensitivity) -> f64| each.iter().map(f).fold(0.0, f64::max);
        let mut rms: Vec<f64> = each.iter().map(|s| s.rms_rel).collect();
        rms.sort_by(f64::total_cmp);
        let median = if rms.len() % 2 == 1 {
            rms[rms.len() / 2]
        } else {
            (rms[rms.len() / 2 - 1] + rms[rms.len() / 2]) / 2.0
        };
        Some(Sensitivity {
            rms_rel: worst.rms_rel,
            max_err_rel: max(|s| s.max_err_rel),
            task_rms_rel: max(|s| s.task_rms_rel),
            tde_rel: each
                .iter()
                .map(|s| s.tde_rel)
                .collect::<Option<Vec<f64>>>()
                .map(|v| v.into_iter().fold(0.0, f64::max)),
            twin_rms_rad: worst.twin_rms_rad,
            twins: each.len() as u32,
            rms_rel_median: median,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn percentile_matches_numpy_type7() {
        // numpy.percentile([1, 2, 3, 4, 10], 99.9) = 9.976
        let mut xs = [4.0, 1.0, 10.0, 3.0, 2.0];
        assert!((percentile_type7(&mut xs, 0.999) - 9.976).abs() < 1e-12);
        let mut ys = [5.0, 1.0];
        assert_eq!(percentile_type7(&mut ys, 0.5), 3.0);
        assert!(percentile_type7(&mut [], 0.5).is_nan());
    }

    #[test]
    fn hf_share_of_pure_tones() {
        let ts = 3e-4;
        // 1001 samples span exactly 0.3 s, so 20 Hz and 200 Hz tones end on zero like they start and
        // the detrend line is zero. Bin spacing 1/(n Ts) ≈ 3.33 Hz; 100 Hz sits at bin ≈ 30.
        let tone = |f: f64| -> Vec<f64> {
            (0..1001)
                .map(|k| (2.0 * std::f64::consts::PI * f * k as f64 * ts).sin())
                .collect()
        };
        // 20 Hz is all low; 200 Hz is all high (up to a little leakage).
        let (_, low_share, low_peak) = high_frequency(&tone(20.0), ts);
        let (hf_rms, high_share, high_peak) = high_frequency(&tone(200.0), ts);
        assert!(low_share < 1e-3, "{low_share}");
        assert!(high_share > 0.995, "{high_share}");
        assert!(
            (low_peak - 20.0).abs() < 0.5 && (high_peak - 200.0).abs() < 0.5,
            "{low_peak} {high_peak}"
        );
        // A unit sine has RMS 1/√2 (the detrend line is ~0 here).
        assert!((hf_rms - 0.5f64.sqrt()).abs() < 5e-3, "{hf_rms}");
        // Bin 30 of n = 1000 at Ts = 0.3 ms is exactly 100 Hz and is not high-frequency
        // (100·30 > 3·1000 is false); bin 31 is.
        assert!(!is_high_frequency(30, 1000, ts));
        assert!(is_high_frequency(31, 1000, ts));
        assert!(!is_high_frequency(3, 100, ts) && is_high_frequency(4, 100, ts));
    }

    #[test]
    fn linear_torque_has_no_hf_content() {
        let tau: Vec<f64> = (0..500).map(|k| 3.0 + 0.01 * k as f64).collect();
        // The detrended series is round-off only, so the HF RMS (not the share of round-off) is ~0.
        let (r, _, _) = high_frequency(&tau, 3e-4);
        assert!(r < 1e-12, "{r}");
    }

    /// The spectrum keeps the detrended series' energy (Parseval: Σ_j w_j·|X_j|² = n·Σ_k d_k²),
    /// in odd and even lengths, and a series too short to detrend has none.
    #[test]
    fn the_one_sided_spectrum_keeps_the_energy_of_the_detrended_series() {
        let mut spectra = Spectra::new();
        for n in [7usize, 8, 1000, 1001] {
            let x: Vec<f64> = (0..n)
                .map(|k| (k as f64 * 0.9).sin() + 0.3 * (k as f64 * 2.1).cos() + 0.02 * k as f64)
                .collect();
            let line = |k: usize| x[0] + (x[n - 1] - x[0]) * k as f64 / (n - 1) as f64;
            let time: f64 = (0..n).map(|k| (x[k] - line(k)).powi(2)).sum::<f64>() * n as f64;
            let e = spectra.detrended(&x);
            assert_eq!(e.len(), n / 2 + 1);
            let freq: f64 = e.iter().sum();
            assert!(
                (freq - time).abs() <= 1e-9 * time,
                "n = {n}: {freq} vs {time}"
            );
        }
        assert!(spectra.detrended(&[1.0]).is_empty());
    }

    #[test]
    fn eq43_k2_requirement() {
        // δ = 0 needs nothing; δ = k1² needs δ·4k1²/(2k1²) = 2δ.
        assert_eq!(k2_required(0.0, 700.0), 0.0);
        assert!((k2_required(4.0, 2.0) - 8.0).abs() < 1e-12);
    }

    /// Up to one segment the streaming chattering analysis is the whole-series FFT, bit for bit.
    #[test]
    fn chatter_stream_equals_the_whole_series_up_to_one_segment() {
        let tau: Vec<f64> = (0..10_001)
            .map(|k| (k as f64 * 0.37).sin() + 1e-3 * k as f64)
            .collect();
        let mut acc = ChatterAcc::new(tau.len());
        tau.iter().for_each(|&x| acc.push(x));
        assert_eq!(acc.finish(3e-4), high_frequency(&tau, 3e-4));
    }

    /// Beyond one segment the memory stays at one segment, and a tone is still found: a ≈200 Hz
    /// sine over 2.5 segments is all high-frequency, with its RMS and its line where they were.
    /// (7864 whole periods per segment, so every segment, the overlapping last one too, starts
    /// and ends on a zero and the detrend line is zero.)
    #[test]
    fn chatter_of_a_long_series_uses_segments_and_finds_the_tone() {
        let ts = 3e-4;
        let f = 7864.0 / (CHATTER_SEGMENT as f64 * ts);
        let n = CHATTER_SEGMENT * 5 / 2;
        let mut acc = ChatterAcc::new(n);
        for k in 0..n {
            acc.push((2.0 * std::f64::consts::PI * f * k as f64 * ts).sin());
        }
        assert_eq!(acc.ring.capacity(), CHATTER_SEGMENT);
        assert_eq!(acc.segments, 2);
        let (rms, share, peak) = acc.finish(ts);
        assert!((rms - 0.5f64.sqrt()).abs() < 5e-3, "{rms}");
        // The segments end one sample short of a zero: their detrend lines take a little.
        assert!(share > 0.9, "{share}");
        assert!((peak - f).abs() < 1e-9, "{peak}");
    }

    /// The streaming p99.9 keeps only the top of the stream and equals numpy's type 7 on all of
    /// it, for counts up to its bound.
    #[test]
    fn tail_percentile_equals_type7_on_the_whole_stream() {
        let bound = 20_000u64;
        for m in [1usize, 2, 3, 999, 1000, 1001, 5_432, 20_000] {
            let xs: Vec<f64> = (0..m)
                .map(|i| ((i as f64 * 7.31).sin() * 1e4).abs() + (i % 13) as f64)
                .collect();
            let mut tail = TailPercentile::new(0.999, bound);
            xs.iter().for_each(|&x| tail.push(x));
            assert!(tail.top.len() <= 24, "kept {}", tail.top.len());
            let mut all = xs.clone();
            assert_eq!(tail.value(), percentile_type7(&mut all, 0.999), "m = {m}");
        }
        assert!(TailPercentile::new(0.999, 0).value().is_nan());
    }

    /// Past the exact bound an HdrHistogram answers, to 3 significant digits.
    #[test]
    fn tail_percentile_of_a_huge_bound_uses_a_histogram() {
        let mut tail = TailPercentile::new(0.999, 1 << 40);
        assert!(tail.hist.is_some() && tail.top.capacity() == 0);
        let xs: Vec<f64> = (1..=100_000).map(|i| i as f64 * 0.5).collect();
        xs.iter().for_each(|&x| tail.push(x));
        let mut all = xs.clone();
        let exact = percentile_type7(&mut all, 0.999);
        let v = tail.value();
        assert!((v - exact).abs() / exact < 1e-3, "{v} vs {exact}");
    }
}
