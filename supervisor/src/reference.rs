//! Joint references per control tick: task path → IK → q_d, q̇_d, q̈_d (docs/delta-robot.md §6). Computed
//! once before a run, so the loop only indexes a table (the controller needs no kinematics).

use crate::scenario::{TaskPath, TaskSample};
use deltaloop_law::Reference;
use deltaloop_model::{DeltaRobot, KinematicsError, Vec3};

/// The reference of one tick: task-space sample plus its joint-space image.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RefRow {
    /// t_k = k·Ts, s.
    pub t: f64,
    /// Task-space reference (m, m/s, m/s²), base frame.
    pub task: TaskSample,
    /// Joint reference (rad, rad/s, rad/s²).
    pub joint: Reference,
}

/// References for ticks k = 0..=N + 1 (one beyond the motion so the last TDE truth has a partner).
#[derive(Clone, Debug)]
pub struct JointReference {
    /// Control period Ts, s.
    pub ts: f64,
    /// Ticks after tick 0 covered by the metrics (N = round((T + hold)/Ts)).
    pub n: usize,
    /// Motion duration T, s (without hold).
    pub duration: f64,
    pub rows: Vec<RefRow>,
}

/// The joint-space image of one task-space sample: q_d = IK(x_d), q̇_d = B⁻¹A ẋ_d,
/// q̈_d = B⁻¹(A ẍ_d − γ) with γ at (q_d, q̇_d, ẋ_d).
pub fn joint_sample(robot: &DeltaRobot, task: &TaskSample) -> Result<Reference, KinematicsError> {
    let q = robot.ik(&task.x)?;
    let pose = robot.pose_at(&q, &task.x);
    let qd = pose.joint_rates(&task.xd);
    let qdd = pose.joint_accels(&task.xd, &task.xdd, &qd);
    Ok(Reference { q, qd, qdd })
}

impl JointReference {
    /// Samples `path` at t_k = k·Ts (never by summing Ts) for k = 0..=n + 1, where n covers the
    /// motion plus `hold_s`. Fails, naming the point, if any reference point is unreachable or
    /// past the singularity margins.
    pub fn build(
        robot: &DeltaRobot,
        path: &TaskPath,
        ts: f64,
        hold_s: f64,
    ) -> Result<Self, KinematicsError> {
        let duration = path.duration();
        let n = ((duration + hold_s) / ts).round() as usize;
        let mut rows = Vec::with_capacity(n + 2);
        for k in 0..=n + 1 {
            let t = k as f64 * ts;
            let task = path.sample(t);
            let joint = joint_sample(robot, &task)?;
            robot.check_margins(&robot.pose_at(&joint.q, &task.x))?;
            rows.push(RefRow { t, task, joint });
        }
        Ok(Self {
            ts,
            n,
            duration,
            rows,
        })
    }

    /// The initial joint angles q_d(0), rad.
    pub fn q0(&self) -> Vec3 {
        self.rows[0].joint.q
    }
}
