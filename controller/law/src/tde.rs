//! Time-delay estimation history (docs/controllers.md, eq. 4–5): the last ℓ pairs
//! (a_{j−1}, τᵃ_j), where a_j = (q̇_{j+1} − q̇_j)/Ts is interval j's mean acceleration and τᵃ_j the
//! torque the drives applied over [t_{j−1}, t_j). At tick k the estimate uses the entry of tick
//! j = k − ℓ + 1: N̂_k = a_{k−ℓ} − M̄⁻¹ τᵃ_{k−ℓ+1}.

use crate::Vec3;

/// Fixed-capacity ring of (a_{j−1} in rad/s², τᵃ_j in N m), oldest first at `head`.
#[derive(Clone, Debug)]
pub struct TdeHistory {
    accel: Vec<Vec3>,
    torque: Vec<Vec3>,
    head: usize,
}

impl TdeHistory {
    /// A history for delay ℓ ≥ 1 ticks, filled as if the robot had rested under `tau_a0` (N m)
    /// before tick 0 (a_j = 0, τᵃ_j = τᵃ_0 for j ≤ 0).
    pub fn new(ell: usize, tau_a0: Vec3) -> Self {
        assert!(ell >= 1, "TDE delay must be at least one tick");
        Self {
            accel: vec![Vec3::zeros(); ell],
            torque: vec![tau_a0; ell],
            head: 0,
        }
    }

    /// The delay ℓ, ticks.
    pub fn delay(&self) -> usize {
        self.accel.len()
    }

    /// Forgets everything and refills as at start-up.
    pub fn reset(&mut self, tau_a0: Vec3) {
        self.accel.fill(Vec3::zeros());
        self.torque.fill(tau_a0);
        self.head = 0;
    }

    /// Records tick k's pair (a_{k−1}, τᵃ_k) and returns the delayed pair (a_{k−ℓ}, τᵃ_{k−ℓ+1}).
    pub fn push(&mut self, accel_prev: Vec3, tau_applied: Vec3) -> (Vec3, Vec3) {
        self.accel[self.head] = accel_prev;
        self.torque[self.head] = tau_applied;
        self.head = (self.head + 1) % self.accel.len();
        // The oldest entry is now at `head`: it was written ℓ − 1 pushes ago.
        (self.accel[self.head], self.torque[self.head])
    }
}
