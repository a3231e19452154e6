//! Delay compensation (docs/controllers.md, "Delay compensation"): the state at the time a
//! torque will act, predicted over the torques already in flight, and the per-joint inertia the
//! prediction needs, learned from measured data.
//!
//! A reply to tick k acts D = d·Ts + δ (0 ≤ δ < Ts) after t_k. At tick k the controller holds
//! q_k, q̇_k, the last interval's acceleration a_{k−1} and applied torque τᵃ_k, and the commands
//! it sent that have not acted yet. Over [t_k, t_k + D) the drives apply those commands, each
//! clamped to ±τ_max, and the TDE model says how the robot answers a torque τ:
//! q̈ = a_{k−1} + (τ − τᵃ_k) / M̂ (per joint). Integrated piece by piece (constant acceleration
//! within a piece), that gives q̂, q̂̇ at t_k + D.

use crate::{Reference, Vec3};

mod delay;
pub use delay::DelayEstimate;

/// The prior of the learned inertia, as a multiple of the law's M̄: the robot's real inertia
/// along the study's paths is 1.2–2.4× M̄ (docs/controllers.md), and a prediction made with too
/// small an inertia overshoots (unstable at whole-tick delays with M̄ itself).
pub const PRIOR_OVER_M_BAR: f64 = 2.0;

/// The learned inertia stays within these multiples of M̄. Below: a prediction with too small an
/// inertia over-corrects, and with M̄ itself is unstable at whole-tick delays. Above: far past
/// any M̄ a user might set too small (the paper's Table I M̄ is 100–230× below the robot's
/// inertia along its paths); too large an inertia only under-corrects.
pub const BOUNDS_OVER_M_BAR: (f64, f64) = (0.5, 1000.0);

/// Forgetting factor of the inertia estimate, per tick that teaches it (a memory of about
/// 1 / (1 − λ) = 2000 such ticks, 0.6 s at Ts = 0.3 ms).
pub const FORGETTING: f64 = 0.9995;

/// A second difference of applied torque (N m) below which a tick teaches the inertia nothing:
/// what the acceleration does then is the robot's own dynamics and the sensor's noise.
pub const MIN_TORQUE_STEP_NM: f64 = 1e-3;

/// Per-joint inertia M̂ (kg m²) learned online: a recursive least-squares fit of
/// Δ²a = θ Δ²τᵃ, θ = 1/M, over the second differences of the measured pairs (a_{k−1}, τᵃ_k),
/// with forgetting and bounds. Model-free: it sees only what the controller measures.
#[derive(Clone, Debug)]
pub struct InertiaEstimate {
    /// θ = 1/M̂ per joint, 1/(kg m²).
    theta: Vec3,
    /// The fit's covariance per joint.
    p: Vec3,
    /// The previous pair (a, τᵃ) and the one before, once there are.
    last: Option<(Vec3, Vec3)>,
    last2: Option<(Vec3, Vec3)>,
    /// θ's bounds, 1/(kg m²): (min, max).
    theta_bounds: (f64, f64),
}

impl InertiaEstimate {
    /// Learning from `m_prior` (kg m², per joint), kept within [lo, hi] (kg m²).
    pub fn learning(m_prior: Vec3, lo: f64, hi: f64) -> Self {
        let theta = m_prior.map(|m| 1.0 / m);
        Self {
            theta,
            // Uncertain by the prior itself, per unit of torque step.
            p: theta.map(|t| t * t * 1e4),
            last: None,
            last2: None,
            theta_bounds: (1.0 / hi, 1.0 / lo),
        }
    }

    /// For the law's M̄ (kg m²): prior and bounds as [`PRIOR_OVER_M_BAR`] and
    /// [`BOUNDS_OVER_M_BAR`] say.
    pub fn for_m_bar(m_bar: f64) -> Self {
        let (lo, hi) = BOUNDS_OVER_M_BAR;
        Self::learning(
            Vec3::repeat(PRIOR_OVER_M_BAR * m_bar),
            lo * m_bar,
            hi * m_bar,
        )
    }

    /// A fixed inertia `m` (kg m², per joint), never updated (a zero covariance: every gain is 0).
    pub fn fixed(m: Vec3) -> Self {
        Self {
            theta: m.map(|m| 1.0 / m),
            p: Vec3::zeros(),
            last: None,
            last2: None,
            theta_bounds: (0.0, f64::INFINITY),
        }
    }

    /// M̂ per joint, kg m².
    pub fn m_hat(&self) -> Vec3 {
        self.theta.map(|t| 1.0 / t)
    }

    /// 1/M̂ per joint, 1/(kg m²).
    pub fn inverse(&self) -> Vec3 {
        self.theta
    }

    /// Learns from tick k's measured pair: `accel` a_{k−1} (rad/s²) with `tau_applied` τᵃ_k
    /// (N m). The fit runs on second differences over the last three pairs,
    /// Δ²a = θ Δ²τᵃ: the unknown term N = a − τᵃ/M changes smoothly, so its second difference
    /// is O(Ts²), where its first difference follows the torque the loop answers it with and
    /// would bias θ.
    pub fn learn(&mut self, accel: Vec3, tau_applied: Vec3) {
        let prev = self.last.replace((accel, tau_applied));
        let prev2 = std::mem::replace(&mut self.last2, prev);
        let (Some((a1, t1)), Some((a2, t2))) = (prev, prev2) else {
            return;
        };
        let (lo, hi) = self.theta_bounds;
        for i in 0..3 {
            let d2a = accel[i] - 2.0 * a1[i] + a2[i];
            let d2t = tau_applied[i] - 2.0 * t1[i] + t2[i];
            if d2t.abs() < MIN_TORQUE_STEP_NM || !d2a.is_finite() {
                continue;
            }
            let p = self.p[i];
            let gain = p * d2t / (FORGETTING + p * d2t * d2t);
            self.theta[i] = (self.theta[i] + gain * (d2a - self.theta[i] * d2t)).clamp(lo, hi);
            self.p[i] = (p - gain * d2t * p) / FORGETTING;
        }
    }
}

/// The delay until a reply acts, split as the predictor walks it: `whole` ticks and `frac`
/// seconds (0 ≤ frac < Ts).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Delay {
    /// d, whole ticks.
    pub whole: usize,
    /// δ, s.
    pub frac: f64,
}

impl Delay {
    /// D = `delay_ns` at period `ts_ns` (both ns, as the config gives them: exact).
    pub fn from_ns(delay_ns: u64, ts_ns: u64) -> Self {
        Self {
            whole: (delay_ns / ts_ns) as usize,
            frac: (delay_ns % ts_ns) as f64 / 1e9,
        }
    }

    /// Commands in flight at a tick: d, and one more whose interval the sub-tick part cuts.
    pub fn in_flight(&self) -> usize {
        self.whole + usize::from(self.frac > 0.0)
    }

    /// D = `s` seconds at period `ts` (s); a negative or non-finite D is 0.
    pub fn from_s(s: f64, ts: f64) -> Self {
        let s = if s.is_finite() { s.max(0.0) } else { 0.0 };
        let whole = (s / ts).floor();
        Self {
            whole: whole as usize,
            frac: (s - whole * ts).clamp(0.0, ts),
        }
    }

    /// D in seconds at period `ts` (s).
    pub fn seconds(&self, ts: f64) -> f64 {
        self.whole as f64 * ts + self.frac
    }
}

/// Predicts the state at t_k + D over the commands in flight. Allocates only in [`Predictor::new`].
#[derive(Clone, Debug)]
pub struct Predictor {
    ts: f64,
    delay: Delay,
    /// Drive limit τ_max, N m (each command is clamped to ±τ_max, as the drives do).
    tau_max: f64,
    /// The commands sent (N m, unclamped), a ring with room for the longest delay it may be
    /// set to; the next is written at `head`.
    sent: Vec<Vec3>,
    head: usize,
    inertia: InertiaEstimate,
}

impl Predictor {
    /// A predictor for delay `delay` at period `ts` (s), drive limit `tau_max` (N m), with
    /// `inertia`.
    pub fn new(delay: Delay, ts: f64, tau_max: f64, inertia: InertiaEstimate) -> Self {
        Self {
            ts,
            delay,
            tau_max,
            sent: vec![Vec3::zeros(); delay.in_flight()],
            head: 0,
            inertia,
        }
    }

    /// The delay it predicts over.
    pub fn delay(&self) -> Delay {
        self.delay
    }

    /// Makes room for delays up to `max` ([`set_delay`](Self::set_delay)); allocates.
    pub fn with_room_for(mut self, max: Delay) -> Self {
        let n = max.in_flight().max(self.sent.len());
        self.sent = vec![Vec3::zeros(); n];
        self.head = 0;
        self
    }

    /// Predicts over `delay` from the next tick on, as long as its commands in flight fit the
    /// room made for them (a longer one is cut to the longest that fits).
    pub fn set_delay(&mut self, delay: Delay) {
        self.delay = if delay.in_flight() <= self.sent.len() {
            delay
        } else {
            Delay {
                whole: self.sent.len(),
                frac: 0.0,
            }
        };
    }

    /// The inertia estimate in use.
    pub fn inertia(&self) -> &InertiaEstimate {
        &self.inertia
    }

    /// Before tick 0 the drives held `tau_a0` (N m): the commands "in flight" are that.
    pub fn reset(&mut self, tau_a0: Vec3) {
        self.sent.fill(tau_a0);
        self.head = 0;
    }

    /// Tick k: learns from (a_{k−1}, τᵃ_k) and predicts (q̂, q̂̇) at t_k + D from q_k (rad),
    /// q̇_k (rad/s), `accel` a_{k−1} (rad/s²) and `tau_applied` τᵃ_k (N m).
    pub fn predict(&mut self, q: Vec3, qd: Vec3, accel: Vec3, tau_applied: Vec3) -> (Vec3, Vec3) {
        self.inertia.learn(accel, tau_applied);
        let inv_m = self.inertia.inverse();
        let (mut q, mut qd) = (q, qd);
        let (cap, n) = (self.sent.len(), self.delay.in_flight());
        for i in 0..n {
            // The last n commands sent, oldest first.
            let cmd = self.sent[(self.head + cap - n + i) % cap];
            // The oldest command acts only for δ when the delay has a sub-tick part.
            let h = if i == 0 && self.delay.frac > 0.0 {
                self.delay.frac
            } else {
                self.ts
            };
            let tau = cmd.map(|t| t.clamp(-self.tau_max, self.tau_max));
            let acc = accel + (tau - tau_applied).component_mul(&inv_m);
            q += qd * h + acc * (0.5 * h * h);
            qd += acc * h;
        }
        (q, qd)
    }

    /// Records τ_k (N m), the command just sent.
    pub fn sent(&mut self, tau: Vec3) {
        let n = self.sent.len();
        if n > 0 {
            self.sent[self.head] = tau;
            self.head = (self.head + 1) % n;
        }
    }
}

/// The reference at t_j + δ from rows j and j + 1 (`frac` δ in s, `ts` Ts): q and q̇ by a
/// second-order step from row j, q̈ linearly between the rows; row j itself when δ = 0. A δ of
/// a tick or more (a measured delay past the one configured) steps from row j + 1 instead, with
/// its q̈.
pub fn reference_ahead(row: &Reference, next: &Reference, frac: f64, ts: f64) -> Reference {
    if frac == 0.0 {
        return *row;
    }
    let (row, frac) = if frac >= ts {
        (next, (frac - ts).min(ts))
    } else {
        (row, frac)
    };
    let w = (frac / ts).min(1.0);
    Reference {
        q: row.q + row.qd * frac + row.qdd * (0.5 * frac * frac),
        qd: row.qd + row.qdd * frac,
        qdd: row.qdd * (1.0 - w) + next.qdd * w,
    }
}

#[cfg(test)]
mod tests;
