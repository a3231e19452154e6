//! A study: one validated config turned into everything a run needs (robot model, reference,
//! controller constants). Built once, read by every law and every loop mode.

use crate::reference::JointReference;
use crate::scenario::TaskPath;
use deltaloop_controller::{Controller, ControllerParams};
use deltaloop_plant::{DeltaRobot, KinematicsError, Plant, SimConfig};
use deltaloop_protocol::{Law, RunConfig};

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

    /// Plant integration settings from the config.
    pub fn sim_config(&self) -> SimConfig {
        SimConfig {
            ts: self.config.loop_.ts_s,
            substeps: self.config.plant.substeps,
            friction: self.config.plant.friction,
            check_margins: true,
            payload_step: None,
        }
    }

    /// A fresh plant at rest at q_d(0).
    pub fn new_plant(&self) -> Result<Plant, KinematicsError> {
        Plant::new(
            self.robot.clone(),
            self.sim_config(),
            self.config.plant.tau_max_nm,
            0,
            self.reference.q0(),
        )
    }

    /// A fresh controller for `law`.
    pub fn new_controller(&self, law: Law) -> Controller {
        Controller::new(
            law,
            self.params,
            self.config.loop_.ts_s,
            self.config.controller.tde_delay_samples as usize,
        )
    }
}
