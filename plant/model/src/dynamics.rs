//! Lagrangian dynamics of the lumped model (docs/delta-robot.md §4): M q̈ + C q̇ + G + d = τ.
//!
//! Joint torques are in N m, inertias in kg m², all vectors in joint space.

use crate::{DeltaRobot, KinematicsError, Mat3, Pose, Vec3};

impl DeltaRobot {
    /// Inertia matrix M(q) = Ib I₃ + mn JᵀJ, kg m².
    pub fn mass(&self, pose: &Pose) -> Mat3 {
        let j = pose.jacobian();
        Mat3::identity() * self.ib + j.transpose() * j * self.mn
    }

    /// Coriolis/centrifugal matrix C(q, q̇) = mn Jᵀ J̇, kg m²/s, for q̇ in rad/s.
    pub fn coriolis(&self, pose: &Pose, qd: &Vec3) -> Mat3 {
        pose.jacobian().transpose() * pose.jdot(qd) * self.mn
    }

    /// The product C(q, q̇) q̇ = mn Jᵀ (J̇ q̇), N m (the only unique part of C).
    pub fn coriolis_qdot(&self, pose: &Pose, qd: &Vec3) -> Vec3 {
        pose.jacobian().transpose() * pose.jdot_qdot(qd) * self.mn
    }

    /// Gravity torque G(q) = −g μ cos q + mn g Jᵀ e_z, N m.
    pub fn gravity(&self, pose: &Pose) -> Vec3 {
        let j = pose.jacobian();
        self.gravity_with(pose, &j)
    }

    fn gravity_with(&self, pose: &Pose, j: &Mat3) -> Vec3 {
        let g = self.p.g;
        let row_z = j.row(2).transpose();
        pose.cos_q * (-g * self.mu) + row_z * (self.mn * g)
    }

    /// Joint friction d_f = Fv q̇ + Fc tanh(q̇/ε), N m, for q̇ in rad/s.
    pub fn friction(&self, qd: &Vec3) -> Vec3 {
        let (fv, fc, eps) = (self.p.fv, self.p.fc, self.p.eps_c);
        qd.map(|w| fv * w + fc * libm::tanh(w / eps))
    }

    /// Inverse dynamics τ = M q̈ + C q̇ + G (d = 0), N m, in the spec's cheap form
    /// τ = Ib q̈ + mn Jᵀ(ẍ + g e_z) − g μ cos q with ẍ = J q̈ + J̇q̇.
    pub fn inverse_dynamics(&self, pose: &Pose, qd: &Vec3, qdd: &Vec3) -> Vec3 {
        let j = pose.jacobian();
        let xdd = j * qdd + pose.jdot_qdot(qd) + Vec3::z() * self.p.g;
        qdd * self.ib + j.transpose() * xdd * self.mn - pose.cos_q * (self.p.g * self.mu)
    }

    /// Forward dynamics q̈ = M⁻¹(τ_net − C q̇ − G), rad/s², where τ_net = τ − d (N m).
    ///
    /// The hot path of the simulation (four calls per RK4 step), so written out: M = Ib I + mn JᵀJ
    /// (symmetric, six entries), C q̇ + G = mn Jᵀ(J̇q̇ + g e_z) − g μ cos q, and a 3×3 Cholesky
    /// solve (M is SPD). Allocates nothing.
    #[inline(always)]
    pub fn forward_dynamics(
        &self,
        pose: &Pose,
        qd: &Vec3,
        tau_net: &Vec3,
    ) -> Result<Vec3, KinematicsError> {
        let j = pose.jacobian();
        let xd = j * qd;
        let jdq = pose.a_inv * pose.gamma(&xd, qd);
        let (ib, mn, g) = (self.ib, self.mn, self.p.g);
        // M = Ib I + mn JᵀJ: m_rc = Ib δ_rc + mn (column r of J)·(column c of J).
        let col = |c: usize| Vec3::new(j[(0, c)], j[(1, c)], j[(2, c)]);
        let (j0, j1, j2) = (col(0), col(1), col(2));
        let m00 = ib + mn * j0.dot(&j0);
        let m11 = ib + mn * j1.dot(&j1);
        let m22 = ib + mn * j2.dot(&j2);
        let m10 = mn * j1.dot(&j0);
        let m20 = mn * j2.dot(&j0);
        let m21 = mn * j2.dot(&j1);
        // rhs = τ_net − C q̇ − G = τ_net − mn Jᵀ(J̇q̇ + g e_z) + g μ cos q.
        let acc = jdq + Vec3::z() * g;
        let gm = g * self.mu;
        let rhs = Vec3::new(
            tau_net[0] - mn * j0.dot(&acc) + gm * pose.cos_q[0],
            tau_net[1] - mn * j1.dot(&acc) + gm * pose.cos_q[1],
            tau_net[2] - mn * j2.dot(&acc) + gm * pose.cos_q[2],
        );
        // Cholesky M = L Lᵀ.
        let l00 = m00.sqrt();
        let l10 = m10 / l00;
        let l20 = m20 / l00;
        let l11 = (m11 - l10 * l10).sqrt();
        let l21 = (m21 - l20 * l10) / l11;
        let l22 = (m22 - l20 * l20 - l21 * l21).sqrt();
        // Not positive definite (only with NaN input: M = Ib I + mn JᵀJ is SPD).
        if l00.is_nan() || l11.is_nan() || l22.is_nan() || l00 <= 0.0 || l11 <= 0.0 || l22 <= 0.0 {
            return Err(KinematicsError::NoAssembly {
                q: [pose.q[0], pose.q[1], pose.q[2]],
            });
        }
        // L y = rhs, then Lᵀ q̈ = y.
        let y0 = rhs[0] / l00;
        let y1 = (rhs[1] - l10 * y0) / l11;
        let y2 = (rhs[2] - l20 * y0 - l21 * y1) / l22;
        let a2 = y2 / l22;
        let a1 = (y1 - l21 * a2) / l11;
        let a0 = (y0 - l10 * a1 - l20 * a2) / l00;
        Ok(Vec3::new(a0, a1, a2))
    }

    /// Kinetic energy T = ½ Ib Σq̇² + ½ mn |ẋ|², J.
    pub fn kinetic_energy(&self, pose: &Pose, qd: &Vec3) -> f64 {
        let xd = pose.jacobian() * qd;
        0.5 * self.ib * qd.norm_squared() + 0.5 * self.mn * xd.norm_squared()
    }

    /// Potential energy V = −g μ Σ sin q + mn g x_z, J (zero at q = 0 arms, platform at z = 0).
    pub fn potential_energy(&self, pose: &Pose) -> f64 {
        let g = self.p.g;
        -g * self.mu * pose.sin_q.sum() + self.mn * g * pose.x[2]
    }

    /// Total energy E = T + V, J.
    pub fn energy(&self, pose: &Pose, qd: &Vec3) -> f64 {
        self.kinetic_energy(pose, qd) + self.potential_energy(pose)
    }
}
