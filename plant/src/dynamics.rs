//! Lagrangian dynamics of the lumped model (spec §4): M q̈ + C q̇ + G + d = τ.
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
        pose.q.map(|qi| -g * self.mu * qi.cos()) + row_z * (self.mn * g)
    }

    /// Joint friction d_f = Fv q̇ + Fc tanh(q̇/ε), N m, for q̇ in rad/s.
    pub fn friction(&self, qd: &Vec3) -> Vec3 {
        let (fv, fc, eps) = (self.p.fv, self.p.fc, self.p.eps_c);
        qd.map(|w| fv * w + fc * (w / eps).tanh())
    }

    /// Inverse dynamics τ = M q̈ + C q̇ + G (d = 0), N m, in the spec's cheap form
    /// τ = Ib q̈ + mn Jᵀ(ẍ + g e_z) − g μ cos q with ẍ = J q̈ + J̇q̇.
    pub fn inverse_dynamics(&self, pose: &Pose, qd: &Vec3, qdd: &Vec3) -> Vec3 {
        let j = pose.jacobian();
        let xdd = j * qdd + pose.jdot_qdot(qd) + Vec3::z() * self.p.g;
        qdd * self.ib + j.transpose() * xdd * self.mn
            - pose.q.map(|qi| self.p.g * self.mu * qi.cos())
    }

    /// Forward dynamics q̈ = M⁻¹(τ_net − C q̇ − G), rad/s², where τ_net = τ − d (N m).
    /// Solved by Cholesky (M is SPD); the whole evaluation allocates nothing.
    pub fn forward_dynamics(
        &self,
        pose: &Pose,
        qd: &Vec3,
        tau_net: &Vec3,
    ) -> Result<Vec3, KinematicsError> {
        let j = pose.jacobian();
        let jt = j.transpose();
        let xd = j * qd;
        let jdq = pose.a_inv * pose.gamma(&xd, qd);
        let m = Mat3::identity() * self.ib + jt * j * self.mn;
        let c_qd = jt * jdq * self.mn;
        let rhs = tau_net - c_qd - self.gravity_with(pose, &j);
        match m.cholesky() {
            Some(ch) => Ok(ch.solve(&rhs)),
            None => Err(KinematicsError::NoAssembly {
                q: [pose.q[0], pose.q[1], pose.q[2]],
            }),
        }
    }

    /// Kinetic energy T = ½ Ib Σq̇² + ½ mn |ẋ|², J.
    pub fn kinetic_energy(&self, pose: &Pose, qd: &Vec3) -> f64 {
        let xd = pose.jacobian() * qd;
        0.5 * self.ib * qd.norm_squared() + 0.5 * self.mn * xd.norm_squared()
    }

    /// Potential energy V = −g μ Σ sin q + mn g x_z, J (zero at q = 0 arms, platform at z = 0).
    pub fn potential_energy(&self, pose: &Pose) -> f64 {
        let g = self.p.g;
        -g * self.mu * pose.q.map(f64::sin).sum() + self.mn * g * pose.x[2]
    }

    /// Total energy E = T + V, J.
    pub fn energy(&self, pose: &Pose, qd: &Vec3) -> f64 {
        self.kinetic_energy(pose, qd) + self.potential_energy(pose)
    }
}
