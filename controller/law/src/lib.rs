//! Model-free control laws for trajectory tracking (docs/controllers.md): `tdc`, `tde-is`,
//! `tdc-is-sta`, `tdc-is-ista` and the `pid` baseline ([`Law::ALL`]), per joint with a diagonal
//! nominal inertia M̄.
//!
//! Pure: no I/O, no clock, no allocation per step (the TDE history is allocated at construction).
//! The controller only sees measured joint data and the applied torque reported by the drives; it
//! knows nothing of the robot model. This crate does not depend on the plant crate.

pub mod law;
pub mod predict;
pub mod sta;
pub mod tde;

pub use law::{Controller, Measurement, Output, Reference};
pub use predict::{Delay, DelayEstimate, InertiaEstimate, Predictor};
// The laws' names and constants are `deltaloop-names`, below the config schema too.
pub use deltaloop_names::{ControllerParams, Law, Preset, VelocitySource};
pub use tde::TdeHistory;

/// Joint-space 3-vector (rad, rad/s, rad/s² or N m, as each field says).
pub type Vec3 = nalgebra::Vector3<f64>;

/// sgn with sgn(0) = 0 (the spec's convention; `f64::signum` returns ±1 at ±0).
pub fn sgn(x: f64) -> f64 {
    if x > 0.0 {
        1.0
    } else if x < 0.0 {
        -1.0
    } else {
        0.0
    }
}

/// sat(x) = clamp(x, −1, 1).
pub fn sat(x: f64) -> f64 {
    x.clamp(-1.0, 1.0)
}
