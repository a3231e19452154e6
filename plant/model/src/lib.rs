//! The Delta robot plant: a 3-DOF lumped-mass (Codourey-type) model of a parallel Delta robot.
//!
//! Pure math, no I/O: parameters ([`params`]), closed-form kinematics ([`kinematics`]), Lagrangian
//! dynamics ([`dynamics`]) and a fixed-step RK4 simulation with zero-order-hold torque ([`sim`]).
//! Nothing here allocates after construction, so the real-time plant process can call it every tick.
//!
//! Frames and units (SI throughout): base frame {O} at the centre of the motor-axis circle, z up,
//! gravity −g e_z. Joint angles q are the upper-arm angles in rad, positive when the elbow is below
//! the base plane. Task position x is the platform centre in {O}, in m.

pub mod dynamics;
pub mod error;
pub mod kinematics;
pub mod params;
pub mod sensor;
pub mod sim;

pub use error::KinematicsError;
pub use kinematics::{Margins, Pose};
pub use params::DeltaParams;
pub use sim::{Actuator, Applied, PayloadStep, Plant, PlantSample, PlantSim, SimConfig};

/// A 3-vector (joint space: rad, rad/s, N m; task space: m, m/s).
pub type Vec3 = nalgebra::Vector3<f64>;
/// A 3×3 matrix, row-major when flattened in test vectors.
pub type Mat3 = nalgebra::Matrix3<f64>;

/// The Delta robot model: parameters plus the quantities derived from them.
///
/// Construct once; every query is allocation-free. `mn` follows the payload so a payload step
/// changes M, C and G consistently (docs/delta-robot.md §4.3).
#[derive(Clone, Debug, PartialEq)]
pub struct DeltaRobot {
    p: DeltaParams,
    /// Radial unit vectors u_i of the arms, base frame.
    u: [Vec3; 3],
    /// Tangential unit vectors v_i = e_z × u_i (motor axis directions), base frame.
    v: [Vec3; 3],
    /// Joint-side inertia of one arm Ib, kg m².
    ib: f64,
    /// Static moment of one arm μ, kg m.
    mu: f64,
    /// Translating mass mn (platform + payload + forearm share), kg.
    mn: f64,
}

impl DeltaRobot {
    /// Builds the model and its derived quantities from primary parameters.
    pub fn new(p: DeltaParams) -> Self {
        let mut u = [Vec3::zeros(); 3];
        let mut v = [Vec3::zeros(); 3];
        for i in 0..3 {
            let phi = p.phi_deg[i].to_radians();
            let (s, c) = phi.sin_cos();
            u[i] = Vec3::new(c, s, 0.0);
            v[i] = Vec3::new(-s, c, 0.0);
        }
        let (ib, mu, mn) = (p.ib(), p.mu(), p.mn());
        Self {
            p,
            u,
            v,
            ib,
            mu,
            mn,
        }
    }

    /// The primary parameters.
    pub fn params(&self) -> &DeltaParams {
        &self.p
    }

    /// Joint-side inertia of one arm Ib, kg m².
    pub fn ib(&self) -> f64 {
        self.ib
    }

    /// Static moment of one arm μ, kg m.
    pub fn mu(&self) -> f64 {
        self.mu
    }

    /// Translating mass mn, kg (includes the current payload).
    pub fn mn(&self) -> f64 {
        self.mn
    }

    /// Sets the payload mass m_pay (kg) and recomputes mn.
    pub fn set_payload(&mut self, m_pay: f64) {
        self.p.m_pay = m_pay;
        self.mn = self.p.mn();
    }
}

impl Default for DeltaRobot {
    fn default() -> Self {
        Self::new(DeltaParams::default())
    }
}
