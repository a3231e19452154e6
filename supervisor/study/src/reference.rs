//! Joint references per control tick: task path → IK → q_d, q̇_d, q̈_d (docs/delta-robot.md §6).
//! Computed on demand, one tick at a time, so a run of hours costs no more memory than a run of
//! seconds; the controller still needs no kinematics (the supervisor sends it the rows).

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

/// The reference for ticks k = 0..=N + 1 (one beyond the motion so the last TDE truth has a
/// partner), validated once and evaluated per tick.
#[derive(Clone, Debug)]
pub struct JointReference {
    /// Control period Ts, s.
    pub ts: f64,
    /// Ticks after tick 0 covered by the metrics (N = round((T + hold)/Ts)).
    pub n: usize,
    /// Motion duration T, s (without hold).
    pub duration: f64,
    robot: DeltaRobot,
    path: TaskPath,
    /// The first tick of the hold: from here on every row is `hold` (but for its time).
    hold_from: usize,
    hold: RefRow,
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

/// The row at t, checked against the workspace and its singularity margins.
fn checked_row(robot: &DeltaRobot, path: &TaskPath, t: f64) -> Result<RefRow, KinematicsError> {
    let task = path.sample(t);
    let joint = joint_sample(robot, &task)?;
    robot.check_margins(&robot.pose_at(&joint.q, &task.x))?;
    Ok(RefRow { t, task, joint })
}

/// Bit equality of two task samples (−0.0 and 0.0 differ: they would print differently).
fn same_bits(a: &TaskSample, b: &TaskSample) -> bool {
    let bits = |s: &TaskSample| {
        let mut v = [0u64; 9];
        for (i, x) in
            s.x.iter()
                .chain(s.xd.iter())
                .chain(s.xdd.iter())
                .enumerate()
        {
            v[i] = x.to_bits();
        }
        v
    };
    bits(a) == bits(b)
}

impl JointReference {
    /// Checks `path` sampled at t_k = k·Ts (never by summing Ts) for k = 0..=n + 1, where n covers
    /// the motion plus `hold_s`. Fails, naming the point, if any reference point is unreachable or
    /// past the singularity margins. Once the path's time law has saturated (the hold) every
    /// sample is the same, so only the motion is walked tick by tick: a long hold costs nothing.
    pub fn build(
        robot: &DeltaRobot,
        path: &TaskPath,
        ts: f64,
        hold_s: f64,
    ) -> Result<Self, KinematicsError> {
        let duration = path.duration();
        let n = ((duration + hold_s) / ts).round() as usize;
        // The end of the path, long after it stopped moving.
        let rest = path.sample(2.0 * duration + 1.0);
        let mut hold_from = n + 2;
        for k in 0..=n + 1 {
            let row = checked_row(robot, path, k as f64 * ts)?;
            if same_bits(&row.task, &rest) {
                hold_from = k;
                break;
            }
        }
        let hold = checked_row(robot, path, hold_from as f64 * ts)?;
        Ok(Self {
            ts,
            n,
            duration,
            robot: robot.clone(),
            path: path.clone(),
            hold_from,
            hold,
        })
    }

    /// The row of tick k (t_k = k·Ts), for any k ≤ N + 1.
    pub fn row(&self, k: usize) -> RefRow {
        let t = k as f64 * self.ts;
        if k >= self.hold_from {
            return RefRow { t, ..self.hold };
        }
        // Every tick before the hold was checked by `build`.
        checked_row(&self.robot, &self.path, t).unwrap_or(RefRow { t, ..self.hold })
    }

    /// Whether tick k lies in the hold, where every row is the same (but for its time).
    pub fn in_hold(&self, k: usize) -> bool {
        k >= self.hold_from
    }

    /// The number of rows, N + 2.
    pub fn row_count(&self) -> usize {
        self.n + 2
    }

    /// The initial joint angles q_d(0), rad.
    pub fn q0(&self) -> Vec3 {
        self.row(0).joint.q
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use deltaloop_config::RunConfig;

    /// Rows computed on demand equal rows sampled one by one, and a long hold repeats the end
    /// point bit for bit (only its time moves on).
    #[test]
    fn on_demand_rows_equal_direct_samples_and_the_hold_is_exact() {
        let cfg = RunConfig::from_toml_str(
            "name = \"r\"\n[scenario]\npath = \"s3\"\nhold_s = 0.5\n",
            None,
        )
        .unwrap();
        let robot = DeltaRobot::default();
        let path = TaskPath::from_section(&cfg.scenario);
        let r = JointReference::build(&robot, &path, 3e-4, 0.5).unwrap();
        assert_eq!(r.row_count(), r.n + 2);
        assert!(r.hold_from > 3000 && r.hold_from < r.n, "{}", r.hold_from);
        for k in (0..r.row_count())
            .step_by(97)
            .chain([r.hold_from - 1, r.hold_from, r.n + 1])
        {
            let direct = checked_row(&robot, &path, k as f64 * 3e-4).unwrap();
            let row = r.row(k);
            assert_eq!(row.t.to_bits(), direct.t.to_bits());
            assert!(same_bits(&row.task, &direct.task), "tick {k}");
            let jb = |j: &Reference| {
                [j.q, j.qd, j.qdd].map(|v| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>())
            };
            assert_eq!(jb(&row.joint), jb(&direct.joint), "tick {k}");
        }
    }
}
