//! The delay until a reply acts, measured from what the drives report (docs/controllers.md,
//! "D in realtime"). A realtime loop adds its own latency to the configured delay D₀, and it
//! varies per tick; the controller cannot see when its reply arrived, but the drives report
//! τᵃ_k, the mean torque they applied over [t_{k−1}, t_k). With the reply to tick j acting from
//! t_j + D, D = m·Ts + x·Ts (0 ≤ x < 1), that interval held command c_{k−m−2} for x·Ts and
//! c_{k−m−1} for the rest:
//!
//!   τᵃ_k = x·c_{k−m−2} + (1 − x)·c_{k−m−1}  (each command clamped as the drives clamp it),
//!
//! so each tick whose two commands differ gives x by least squares over the joints, for each m
//! that D₀ ≤ D ≤ D₀ + Ts allows, the m that fits best winning. The estimate in use is the median
//! of the last [`WINDOW`] such ticks (a missed or dropped reply, which the drives held over,
//! gives one wrong tick, not a wrong estimate); before the first, D₀. Only the controller's own
//! commands and the drives' report are used, on one host or across two, never a clock of the
//! plant's.

use super::Delay;
use crate::Vec3;

/// Ticks the estimate is the median of.
pub const WINDOW: usize = 31;

/// Two commands closer than this (N m, over the joints) say nothing of when one followed the other.
const MIN_STEP_NM: f64 = 1e-6;

/// The delay D (s) until a reply acts, measured from the drives' reports. Allocates only in
/// [`DelayEstimate::new`].
#[derive(Clone, Debug)]
pub struct DelayEstimate {
    ts: f64,
    tau_max: f64,
    /// D₀, s: the estimate lies in [D₀, D₀ + Ts].
    base: f64,
    /// The commands sent, by tick: slot j mod len holds (j, c_j clamped).
    sent: Vec<(u64, Vec3)>,
    /// The last per-tick estimates (s), a ring of which `filled` are set.
    window: [f64; WINDOW],
    filled: usize,
    next: usize,
    /// The estimate in use, s.
    current: f64,
}

impl DelayEstimate {
    /// Measures D from `base` (the configured D₀) up to one tick more, at period `ts` (s), for
    /// drives clamping to ±`tau_max` (N m).
    pub fn new(base: Delay, ts: f64, tau_max: f64) -> Self {
        let base_s = base.seconds(ts);
        Self {
            ts,
            tau_max,
            base: base_s,
            // c_{k−m−2} for the largest m: D₀ + Ts is at most base.whole + 2 ticks.
            sent: vec![(u64::MAX, Vec3::zeros()); base.whole + 4],
            window: [0.0; WINDOW],
            filled: 0,
            next: 0,
            current: base_s,
        }
    }

    /// The longest delay it may report: D₀ + Ts.
    pub fn max(&self) -> Delay {
        Delay::from_s(self.base + self.ts, self.ts)
    }

    /// The delay in use.
    pub fn delay(&self) -> Delay {
        Delay::from_s(self.current, self.ts)
    }

    /// Records c_k, the command sent for tick `k` (N m, as sent: clamped here as the drives
    /// clamp it).
    pub fn sent(&mut self, k: u64, tau: Vec3) {
        let n = self.sent.len() as u64;
        self.sent[(k % n) as usize] = (k, tau.map(|t| t.clamp(-self.tau_max, self.tau_max)));
    }

    /// Learns from τᵃ_k (N m), the drives' report in the state of tick `k`.
    pub fn observe(&mut self, k: u64, tau_applied: Vec3) {
        // A non-finite report or command (a fault) teaches nothing.
        let Some(d) = self.one_tick(k, tau_applied).filter(|d| d.is_finite()) else {
            return;
        };
        self.window[self.next] = d;
        self.next = (self.next + 1) % WINDOW;
        self.filled = (self.filled + 1).min(WINDOW);
        let mut w = self.window;
        let w = &mut w[..self.filled];
        let mid = w.len() / 2;
        self.current = *w.select_nth_unstable_by(mid, f64::total_cmp).1;
    }

    /// c_j, if it was sent (and not overwritten since).
    fn command(&self, j: u64) -> Option<Vec3> {
        let (tick, c) = self.sent[(j % self.sent.len() as u64) as usize];
        (tick == j).then_some(c)
    }

    /// Tick k's own estimate of D (s): the best fit over the whole ticks m that D₀ ≤ D ≤ D₀ + Ts
    /// allows; None when no m has both commands, or they do not differ.
    fn one_tick(&self, k: u64, tau_applied: Vec3) -> Option<f64> {
        let (lo, hi) = (self.base, self.base + self.ts);
        let (m_lo, m_hi) = ((lo / self.ts).floor() as u64, (hi / self.ts).floor() as u64);
        let mut best: Option<(f64, f64)> = None;
        for m in m_lo..=m_hi {
            let (Some(j_old), Some(j_new)) = (k.checked_sub(m + 2), k.checked_sub(m + 1)) else {
                continue;
            };
            let (Some(old), Some(new)) = (self.command(j_old), self.command(j_new)) else {
                continue;
            };
            let step = old - new;
            let den = step.norm_squared();
            if den < MIN_STEP_NM * MIN_STEP_NM {
                continue;
            }
            let x = ((tau_applied - new).dot(&step) / den).clamp(0.0, 1.0);
            let residual = (tau_applied - new - step * x).norm_squared();
            let d = ((m as f64 + x) * self.ts).clamp(lo, hi);
            if best.is_none_or(|(r, _)| residual < r) {
                best = Some((residual, d));
            }
        }
        best.map(|(_, d)| d)
    }
}
