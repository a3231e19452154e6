//! A study: one validated config turned into everything a run needs (robot model, reference,
//! controller constants). Built once, read by every law and every loop mode. And the recorder
//! every loop mode feeds, with the one-pass metrics ([`record`]). No I/O.
//!
//! Pure: it stands on the model, the laws and both sides' ticks, and on no transport, no command
//! line and no process code (tests/e2e/crate_graph.rs), so what a run computes is the same
//! whichever loop carries it. The supervisor re-exports it as its bottom layers (`study`,
//! `record`).

pub mod analysis;
pub mod record;
pub mod reference;
pub mod scenario;

/// An empty latency histogram, ns: 1 ns to 100 s at 3 significant digits, the bounds of every
/// latency and timing histogram deltaloop keeps.
pub fn latency_histogram() -> hdrhistogram::Histogram<u64> {
    hdrhistogram::Histogram::new_with_bounds(1, 100_000_000_000, 3).expect("valid bounds")
}

use crate::reference::JointReference;
use crate::scenario::TaskPath;
use deltaloop_config::{Law, RunConfig};
use deltaloop_controller_tick::ControllerSide;
use deltaloop_law::ControllerParams;
use deltaloop_model::{DeltaRobot, KinematicsError, Vec3};
use deltaloop_plant_tick::PlantSide;

/// The resolved inputs of a run.
#[derive(Clone, Debug)]
pub struct Study {
    pub config: RunConfig,
    pub robot: DeltaRobot,
    pub path: TaskPath,
    pub reference: JointReference,
    pub params: ControllerParams,
}

impl Study {
    /// Builds the reference for a validated config. Fails (naming the point) if the path leaves
    /// the reachable, well-conditioned workspace.
    pub fn new(config: RunConfig) -> Result<Self, KinematicsError> {
        let robot = DeltaRobot::default();
        let path = TaskPath::from_section(&config.scenario);
        let reference =
            JointReference::build(&robot, &path, config.loop_.ts_s, config.scenario.hold_s)?;
        let params = config.controller_params();
        Ok(Self {
            config,
            robot,
            path,
            reference,
            params,
        })
    }

    /// The plant side of a fresh run: the plant at rest at q_d(0), as the config describes it,
    /// for ticks 0..=N.
    pub fn plant_side(&self) -> Result<PlantSide, KinematicsError> {
        self.plant_side_at(self.reference.q0())
    }

    /// [`Self::plant_side`] with the plant at rest at `q0` (rad, joint space) instead.
    pub fn plant_side_at(&self, q0: Vec3) -> Result<PlantSide, KinematicsError> {
        PlantSide::from_config(&self.config, q0, self.reference.n as u64)
    }

    /// The round-off twin's initial joint angles, rad: q_d(0) with every joint moved to the
    /// next larger `f64` (one ulp, ≈ 1e-16 rad at these angles). A perturbation at the level
    /// of the arithmetic's own rounding: a result that changes by more than round-off under it
    /// is sensitive to how the arithmetic is ordered, not only to the physics.
    pub fn twin_q0(&self) -> Vec3 {
        self.reference.q0().map(f64::next_up)
    }

    /// The starting angles of every round-off twin ([`crate::record::sensitivity::PERTURBATION`]):
    /// q(0) one ulp up and one ulp down in each joint alone (6), and in all three together (2).
    pub fn twin_q0s(&self) -> Vec<Vec3> {
        let q0 = self.reference.q0();
        let mut out = Vec::with_capacity(8);
        for step in [f64::next_up as fn(f64) -> f64, f64::next_down] {
            for j in 0..3 {
                let mut q = q0;
                q[j] = step(q[j]);
                out.push(q);
            }
            out.push(q0.map(step));
        }
        out
    }

    /// The controller side of a fresh run of `law`.
    pub fn controller_side(&self, law: Law) -> ControllerSide {
        ControllerSide::from_config(&self.config, law)
    }
}
