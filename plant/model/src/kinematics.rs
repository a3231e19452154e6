//! Closed-form kinematics (docs/delta-robot.md §3): IK (elbow-out branch), FK (three-sphere intersection, lower
//! root), the Jacobian J = A⁻¹B, its inverse, J̇q̇ and J̇, and the singularity margins.

use crate::{DeltaRobot, KinematicsError, Mat3, Vec3};

/// Singularity margin limit: flag S/Lb or |det(A/Lb)| below this (docs/delta-robot.md §3.5).
pub const MARGIN_LIMIT: f64 = 0.05;

/// Everything the velocity and dynamics formulas need at one configuration q, computed once.
///
/// All vectors are in the base frame. `d[i]` is forearm i (m), `t[i]` = ∂E_i/∂q_i (m/rad),
/// `n[i]` = ∂t_i/∂q_i (m/rad²), `beta[i]` = d_i·t_i (m²/rad).
#[derive(Clone, Copy, Debug)]
pub struct Pose {
    /// Joint angles, rad.
    pub q: Vec3,
    /// Platform centre x = FK(q), m.
    pub x: Vec3,
    /// Forearm vectors d_i = P_i − E_i, m.
    pub d: [Vec3; 3],
    /// Elbow velocity directions t_i = ∂E_i/∂q_i, m/rad.
    pub t: [Vec3; 3],
    /// Second derivatives n_i = ∂t_i/∂q_i, m/rad².
    pub n: [Vec3; 3],
    /// β_i = d_i·t_i, m²/rad (positive on the elbow-out branch).
    pub beta: Vec3,
    /// A⁻¹ where A has rows d_iᵀ, 1/m.
    pub a_inv: Mat3,
    /// det A, m³.
    pub det_a: f64,
    /// sin q_i and cos q_i (kept for gravity and energy).
    pub sin_q: Vec3,
    pub cos_q: Vec3,
}

/// Distance from the two kinds of singularity (docs/delta-robot.md §3.5); both dimensionless.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Margins {
    /// min_i S_i/Lb = β_i/(La Lb): serial singularity when it reaches 0.
    pub s_over_lb: f64,
    /// |det(A/Lb)|: parallel singularity when it reaches 0.
    pub det_a_norm: f64,
}

impl Margins {
    /// True when both margins are at or above [`MARGIN_LIMIT`].
    pub fn ok(&self) -> bool {
        self.s_over_lb >= MARGIN_LIMIT && self.det_a_norm >= MARGIN_LIMIT
    }
}

/// (sin q_i, cos q_i), one call per joint. The plant uses the pure-Rust `libm` for its
/// transcendental functions: faster here than the system's, and the same bits on every machine.
#[inline(always)]
fn sin_cos(q: &Vec3) -> (Vec3, Vec3) {
    let (s0, c0) = libm::sincos(q[0]);
    let (s1, c1) = libm::sincos(q[1]);
    let (s2, c2) = libm::sincos(q[2]);
    (Vec3::new(s0, s1, s2), Vec3::new(c0, c1, c2))
}

fn arr(v: &Vec3) -> [f64; 3] {
    [v[0], v[1], v[2]]
}

impl DeltaRobot {
    /// Sphere centres C_i = E_i(q_i) − r u_i (m) from sin q_i and cos q_i, where the elbow is
    /// E_i = A_i + La (cos q_i u_i − sin q_i e_z).
    #[inline(always)]
    fn sphere_centres(&self, sin_q: &Vec3, cos_q: &Vec3) -> [Vec3; 3] {
        let (la, rr) = (
            self.p.upper_arm,
            self.p.base_radius - self.p.platform_radius,
        );
        // Written per component: u_i has no z part, and IEEE rules keep 0·x from being folded.
        std::array::from_fn(|i| {
            let radial = rr + la * cos_q[i];
            Vec3::new(self.u[i][0] * radial, self.u[i][1] * radial, -la * sin_q[i])
        })
    }

    /// Inverse kinematics, elbow-out branch (docs/delta-robot.md §3.1): platform position x (m) → q (rad).
    pub fn ik(&self, x: &Vec3) -> Result<Vec3, KinematicsError> {
        let (la, lb) = (self.p.upper_arm, self.p.forearm);
        let mut q = Vec3::zeros();
        for i in 0..3 {
            let w = x + self.u[i] * (self.p.platform_radius - self.p.base_radius);
            let a = w.dot(&self.u[i]);
            let b = w.dot(&self.v[i]);
            let c = w[2];
            let k = (a * a + b * b + c * c + la * la - lb * lb) / (2.0 * la);
            let rho2 = a * a + c * c;
            let radicand = rho2 - k * k;
            if radicand.is_nan() || radicand <= 0.0 {
                return Err(KinematicsError::Unreachable {
                    x: arr(x),
                    arm: i,
                    radicand,
                });
            }
            let s = radicand.sqrt();
            q[i] = libm::atan2(-c * k - a * s, a * k - c * s);
        }
        Ok(q)
    }

    /// Forward kinematics (docs/delta-robot.md §3.2): q (rad) → platform position x (m), the lower root.
    pub fn fk(&self, q: &Vec3) -> Result<Vec3, KinematicsError> {
        self.pose(q).map(|p| p.x)
    }

    /// Three-sphere intersection (lower root) of the centres C_i with radius Lb.
    #[inline(always)]
    fn intersect(&self, q: &Vec3, c: &[Vec3; 3]) -> Result<Vec3, KinematicsError> {
        let a = c[1] - c[0];
        let b = c[2] - c[0];
        let w = a.cross(&b);
        let w2 = w.norm_squared();
        let fail = KinematicsError::NoAssembly { q: arr(q) };
        // Collinear centres (or NaN input): no unique circumcircle.
        if w2.is_nan() || w2 <= 1e-24 {
            return Err(fail);
        }
        let m = c[0] + (b * a.norm_squared() - a * b.norm_squared()).cross(&w) / (2.0 * w2);
        let lb = self.p.forearm;
        let rad = lb * lb - (m - c[0]).norm_squared();
        if rad.is_nan() || rad < 0.0 {
            return Err(fail);
        }
        let mut n = w / w2.sqrt();
        if n[2] > 0.0 {
            n = -n;
        }
        Ok(m + n * rad.sqrt())
    }

    /// The geometry at q (FK plus the forearm vectors, A⁻¹ and β); the building block of every
    /// velocity and dynamics query. One sin/cos per joint.
    #[inline(always)]
    pub fn pose(&self, q: &Vec3) -> Result<Pose, KinematicsError> {
        let (sin_q, cos_q) = sin_cos(q);
        let c = self.sphere_centres(&sin_q, &cos_q);
        let x = self.intersect(q, &c)?;
        Ok(self.assemble(q, &x, sin_q, cos_q, &c))
    }

    /// As [`pose`](Self::pose), with the platform position x = FK(q) already known (m).
    #[inline(always)]
    pub fn pose_at(&self, q: &Vec3, x: &Vec3) -> Pose {
        let (sin_q, cos_q) = sin_cos(q);
        let c = self.sphere_centres(&sin_q, &cos_q);
        self.assemble(q, x, sin_q, cos_q, &c)
    }

    #[inline(always)]
    fn assemble(&self, q: &Vec3, x: &Vec3, sin_q: Vec3, cos_q: Vec3, c: &[Vec3; 3]) -> Pose {
        let la = self.p.upper_arm;
        // d_i = P_i − E_i = (x + r u_i) − E_i = x − C_i.
        let d: [Vec3; 3] = std::array::from_fn(|i| x - c[i]);
        // t_i = −La (sin q_i u_i + cos q_i e_z), n_i = −La (cos q_i u_i − sin q_i e_z).
        let t: [Vec3; 3] = std::array::from_fn(|i| {
            let r = -la * sin_q[i];
            Vec3::new(self.u[i][0] * r, self.u[i][1] * r, -la * cos_q[i])
        });
        let n: [Vec3; 3] = std::array::from_fn(|i| {
            let r = -la * cos_q[i];
            Vec3::new(self.u[i][0] * r, self.u[i][1] * r, la * sin_q[i])
        });
        let beta = Vec3::new(d[0].dot(&t[0]), d[1].dot(&t[1]), d[2].dot(&t[2]));
        let c0 = d[1].cross(&d[2]);
        let c1 = d[2].cross(&d[0]);
        let c2 = d[0].cross(&d[1]);
        let det_a = d[0].dot(&c0);
        let a_inv = Mat3::from_columns(&[c0, c1, c2]) * (1.0 / det_a);
        Pose {
            q: *q,
            x: *x,
            d,
            t,
            n,
            beta,
            a_inv,
            det_a,
            sin_q,
            cos_q,
        }
    }

    /// Singularity margins at a pose (docs/delta-robot.md §3.5).
    pub fn margins(&self, pose: &Pose) -> Margins {
        let (la, lb) = (self.p.upper_arm, self.p.forearm);
        Margins {
            s_over_lb: pose.beta.min() / (la * lb),
            det_a_norm: (pose.det_a / (lb * lb * lb)).abs(),
        }
    }

    /// An error naming the configuration when the pose is past the singularity margins.
    pub fn check_margins(&self, pose: &Pose) -> Result<Margins, KinematicsError> {
        let m = self.margins(pose);
        if m.ok() {
            Ok(m)
        } else {
            Err(KinematicsError::Singular {
                q: arr(&pose.q),
                s_over_lb: m.s_over_lb,
                det_a_norm: m.det_a_norm,
                limit: MARGIN_LIMIT,
            })
        }
    }
}

impl Pose {
    /// Jacobian J = A⁻¹B (ẋ = J q̇), m/rad.
    #[inline(always)]
    pub fn jacobian(&self) -> Mat3 {
        let mut j = self.a_inv;
        for i in 0..3 {
            j.column_mut(i).scale_mut(self.beta[i]);
        }
        j
    }

    /// Inverse Jacobian J⁻¹ = B⁻¹A (row i = d_iᵀ/β_i), rad/m.
    pub fn jacobian_inv(&self) -> Mat3 {
        Mat3::from_rows(&[
            (self.d[0] / self.beta[0]).transpose(),
            (self.d[1] / self.beta[1]).transpose(),
            (self.d[2] / self.beta[2]).transpose(),
        ])
    }

    /// ḋ_i = ẋ − t_i q̇_i, m/s, for a platform velocity ẋ (m/s) and joint rates q̇ (rad/s).
    fn d_dot(&self, xd: &Vec3, qd: &Vec3) -> [Vec3; 3] {
        std::array::from_fn(|i| xd - self.t[i] * qd[i])
    }

    /// γ_i = (d_i·n_i) q̇_i² − |ḋ_i|², m²/s² (docs/delta-robot.md §3.4), given ẋ (m/s) and q̇ (rad/s).
    #[inline(always)]
    pub fn gamma(&self, xd: &Vec3, qd: &Vec3) -> Vec3 {
        let dd = self.d_dot(xd, qd);
        Vec3::from_fn(|i, _| self.d[i].dot(&self.n[i]) * qd[i] * qd[i] - dd[i].norm_squared())
    }

    /// J̇ q̇ = A⁻¹γ, m/s², for joint rates q̇ (rad/s).
    pub fn jdot_qdot(&self, qd: &Vec3) -> Vec3 {
        let xd = self.jacobian() * qd;
        self.a_inv * self.gamma(&xd, qd)
    }

    /// J̇ = A⁻¹ (diag(β̇) − Ȧ J), m/(rad s), for joint rates q̇ (rad/s).
    pub fn jdot(&self, qd: &Vec3) -> Mat3 {
        let j = self.jacobian();
        let xd = j * qd;
        let dd = self.d_dot(&xd, qd);
        let a_dot = Mat3::from_rows(&[dd[0].transpose(), dd[1].transpose(), dd[2].transpose()]);
        let beta_dot =
            Vec3::from_fn(|i, _| dd[i].dot(&self.t[i]) + self.d[i].dot(&self.n[i]) * qd[i]);
        self.a_inv * (Mat3::from_diagonal(&beta_dot) - a_dot * j)
    }

    /// Joint rates from a platform velocity: q̇ = B⁻¹A ẋ, rad/s (ẋ in m/s).
    pub fn joint_rates(&self, xd: &Vec3) -> Vec3 {
        Vec3::from_fn(|i, _| self.d[i].dot(xd) / self.beta[i])
    }

    /// Joint accelerations from platform motion: q̈ = B⁻¹(A ẍ − γ), rad/s², with γ at (q, q̇, ẋ).
    pub fn joint_accels(&self, xd: &Vec3, xdd: &Vec3, qd: &Vec3) -> Vec3 {
        let g = self.gamma(xd, qd);
        Vec3::from_fn(|i, _| (self.d[i].dot(xdd) - g[i]) / self.beta[i])
    }
}
