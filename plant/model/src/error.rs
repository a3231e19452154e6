//! Kinematic failures: every one names the point or configuration it happened at.

use thiserror::Error;

/// Why a kinematic or dynamic query has no valid answer. Never a NaN: callers get the point.
#[derive(Clone, Copy, Debug, Error, PartialEq)]
pub enum KinematicsError {
    /// Inverse kinematics: arm `arm` cannot reach the platform point (ρ² − K² ≤ 0).
    #[error(
        "task point x = ({:.6}, {:.6}, {:.6}) m is unreachable: arm {} has rho^2 - K^2 = {:.3e} m^2 (must be > 0)",
        x[0], x[1], x[2], arm + 1, radicand
    )]
    Unreachable {
        x: [f64; 3],
        arm: usize,
        radicand: f64,
    },
    /// Forward kinematics: the three spheres do not intersect (or their centres are collinear).
    #[error(
        "joint configuration q = ({:.6}, {:.6}, {:.6}) rad cannot be assembled (forward kinematics has no solution)",
        q[0], q[1], q[2]
    )]
    NoAssembly { q: [f64; 3] },
    /// The integrated state is not finite (the simulation diverged).
    #[error("the simulated state became non-finite at q = ({:.6}, {:.6}, {:.6}) rad: the simulation diverged", q[0], q[1], q[2])]
    NonFinite { q: [f64; 3] },
    /// The configuration is past the singularity margins (S/Lb or |det(A/Lb)| below the limit).
    #[error(
        "joint configuration q = ({:.6}, {:.6}, {:.6}) rad is past the singularity margins: min S/Lb = {:.4}, |det(A/Lb)| = {:.4} (both must be >= {})",
        q[0], q[1], q[2], s_over_lb, det_a_norm, limit
    )]
    Singular {
        q: [f64; 3],
        s_over_lb: f64,
        det_a_norm: f64,
        limit: f64,
    },
}
