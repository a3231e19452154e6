//! Task-space reference paths (docs/delta-robot.md §6): semi-elliptic segments traversed with the
//! rest-to-rest quintic time law, and the paper's scenarios S1, S2, S3.

use deltaloop_config::{PathKind, ScenarioSection, Segment};
use deltaloop_model::Vec3;

/// P0 = (0.25, 0, −0.43) m, the start of every paper scenario.
pub const P0: [f64; 3] = [0.25, 0.0, -0.43];
/// P1 = (0, 0.15, −0.43) m, S3's via point.
pub const P1: [f64; 3] = [0.0, 0.15, -0.43];
/// P2 = (−0.25, 0, −0.43) m, the end of every paper scenario.
pub const P2: [f64; 3] = [-0.25, 0.0, -0.43];
/// Apex height of the paper's semi-ellipses, m.
pub const APEX: f64 = 0.12;

/// Rest-to-rest quintic time law at t (s) for duration T (s): (s, ṡ in 1/s, s̈ in 1/s²).
pub fn quintic(t: f64, duration: f64) -> (f64, f64, f64) {
    let u = (t / duration).clamp(0.0, 1.0);
    let s = 10.0 * u.powi(3) - 15.0 * u.powi(4) + 6.0 * u.powi(5);
    let sd = 30.0 * u * u * (1.0 - u) * (1.0 - u) / duration;
    let sdd = 60.0 * u * (1.0 - u) * (1.0 - 2.0 * u) / (duration * duration);
    (s, sd, sdd)
}

/// Task-space position (m), velocity (m/s) and acceleration (m/s²) of the platform, base frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TaskSample {
    pub x: Vec3,
    pub xd: Vec3,
    pub xdd: Vec3,
}

/// A sequence of semi-elliptic segments, each starting when the previous one ends.
#[derive(Clone, Debug, PartialEq)]
pub struct TaskPath {
    segments: Vec<Segment>,
}

impl TaskPath {
    /// The path a scenario section describes.
    pub fn from_section(s: &ScenarioSection) -> Self {
        let seg = |from, to, duration_s| Segment {
            from,
            to,
            apex_m: APEX,
            duration_s,
        };
        let segments = match s.path {
            PathKind::S1 => vec![seg(P0, P2, 0.8)],
            PathKind::S2 => vec![seg(P0, P2, 0.2)],
            PathKind::S3 => vec![seg(P0, P1, 0.6), seg(P1, P2, 0.6)],
            PathKind::Custom => s.segments.clone(),
        };
        Self { segments }
    }

    /// Total motion duration T, s.
    pub fn duration(&self) -> f64 {
        self.segments.iter().map(|s| s.duration_s).sum()
    }

    /// The end point, m.
    pub fn end(&self) -> Vec3 {
        Vec3::from(self.segments.last().expect("a path has segments").to)
    }

    /// The reference at time t (s). Segment i covers [t_i, t_i + T_i) in local time t − t_i; after
    /// the last segment the end point is held (its time law saturates).
    pub fn sample(&self, t: f64) -> TaskSample {
        let mut start = 0.0;
        let last = self.segments.len() - 1;
        for (i, seg) in self.segments.iter().enumerate() {
            if i == last || t < start + seg.duration_s {
                return semi_ellipse(seg, t - start);
            }
            start += seg.duration_s;
        }
        unreachable!("the last segment always answers")
    }

    /// The ticks k < `end` (t_k = k·Ts) each segment answers for in [`Self::sample`], found in
    /// closed form: segment i's from the first tick at or after its start to the first at or
    /// after its end (the last segment's to `end`).
    pub fn spans(&self, ts: f64, end: u64) -> Vec<Span> {
        let mut out = Vec::with_capacity(self.segments.len());
        let mut start = 0.0;
        let last = self.segments.len() - 1;
        for (i, seg) in self.segments.iter().enumerate() {
            let from = first_tick_at(start, ts).min(end);
            let to = if i == last {
                end
            } else {
                first_tick_at(start + seg.duration_s, ts).min(end)
            };
            out.push(Span {
                segment: i,
                start_s: start,
                ticks: from..to.max(from),
            });
            start += seg.duration_s;
        }
        out
    }

    /// The reference at time t (s) within `span`: what [`Self::sample`] gives for a t of its
    /// ticks, without looking for the segment.
    pub fn sample_in(&self, span: &Span, t: f64) -> TaskSample {
        semi_ellipse(&self.segments[span.segment], t - span.start_s)
    }
}

/// The ticks of one segment ([`TaskPath::spans`]).
#[derive(Clone, Debug, PartialEq)]
pub struct Span {
    /// The segment's index.
    pub segment: usize,
    /// Its start, s (the durations before it summed as [`TaskPath::sample`] sums them).
    pub start_s: f64,
    /// Its ticks k (t_k = k·Ts).
    pub ticks: std::ops::Range<u64>,
}

/// The first tick k with k·Ts ≥ t (t_k computed as every reader computes it, `k as f64 * ts`).
pub fn first_tick_at(t: f64, ts: f64) -> u64 {
    // `as` saturates; the loops below fix the division's round-off (a step or two).
    let mut k = (t / ts).ceil().max(0.0) as u64;
    while k > 0 && (k - 1) as f64 * ts >= t {
        k -= 1;
    }
    while (k as f64 * ts) < t {
        k += 1;
    }
    k
}

/// A semi-ellipse from P_a to P_b with apex h (docs/delta-robot.md §6), at local time t (s).
fn semi_ellipse(seg: &Segment, t: f64) -> TaskSample {
    let (pa, pb) = (Vec3::from(seg.from), Vec3::from(seg.to));
    let c = (pa + pb) / 2.0;
    let w = (pa - pb) / 2.0;
    let hz = Vec3::z() * seg.apex_m;
    let (s, sd, sdd) = quintic(t, seg.duration_s);
    let pi = std::f64::consts::PI;
    let (sn, cs) = (pi * s).sin_cos();
    let p = c + w * cs + hz * sn;
    let p1 = (-w * sn + hz * cs) * pi;
    let p2 = -(w * cs + hz * sn) * (pi * pi);
    TaskSample {
        x: p,
        xd: p1 * sd,
        xdd: p2 * (sd * sd) + p1 * sdd,
    }
}
