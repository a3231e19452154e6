//! A study: one validated config turned into everything a run needs (robot model, reference,
//! controller constants). Built once, read by every law and every loop mode.

use crate::reference::JointReference;
use crate::scenario::TaskPath;
use deltaloop_controller::{Controller, ControllerParams};
use deltaloop_plant::{DeltaRobot, KinematicsError, Plant};
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

    /// A fresh plant at rest at q_d(0), as the config describes it.
    pub fn new_plant(&self) -> Result<Plant, KinematicsError> {
        deltaloop_plant::process::plant_from_config(&self.config, self.reference.q0())
    }

    /// A fresh controller for `law`.
    pub fn new_controller(&self, law: Law) -> Controller {
        Controller::new(
            law,
            self.params,
            self.config.loop_.ts_s,
            self.config.controller.tde_delay_samples as usize,
        )
        .with_velocity(self.config.sensor.velocity)
    }
}
