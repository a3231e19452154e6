//! Joint references per control tick: task path → IK → q_d, q̇_d, q̈_d (docs/delta-robot.md §6).
//! Computed on demand, one tick at a time, so a run of hours costs no more memory than a run of
//! seconds; the controller still needs no kinematics (the supervisor sends it the rows).

use crate::scenario::{Span, TaskPath, TaskSample, first_tick_at};
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
    checked_sample(robot, path.sample(t), t)
}

/// The row of `task` at t, checked as [`checked_row`] checks it.
fn checked_sample(robot: &DeltaRobot, task: TaskSample, t: f64) -> Result<RefRow, KinematicsError> {
    let joint = joint_sample(robot, &task)?;
    robot.check_margins(&robot.pose_at(&joint.q, &task.x))?;
    Ok(RefRow { t, task, joint })
}

/// Most motion ticks [`JointReference::build`] checks: 2^18, a motion of 79 s at Ts = 0.3 ms
/// tick by tick, about 0.1 s of work.
pub const MAX_CHECKED_TICKS: u64 = 1 << 18;

/// The ticks of each span to check, at most `budget` in all (but for each span's first and
/// last): every tick of a span with at most C ticks, else C of them evenly spread, its first and
/// last included, where C is the largest share that keeps the total within the budget (a short
/// segment among long ones keeps all its ticks).
pub fn checked_ticks(spans: &[Span], budget: u64) -> Vec<Vec<u64>> {
    let len = |s: &Span| s.ticks.end - s.ticks.start;
    let total = |c: u64| spans.iter().map(|s| len(s).min(c)).sum::<u64>();
    let longest = spans.iter().map(len).max().unwrap_or(0);
    // The largest share c with total(c) <= budget (total grows with c).
    let (mut lo, mut hi) = (2, longest.max(2));
    while lo < hi {
        let mid = lo + (hi - lo).div_ceil(2);
        if total(mid) <= budget {
            lo = mid;
        } else {
            hi = mid - 1;
        }
    }
    let share = lo;
    spans
        .iter()
        .map(|s| {
            let m = len(s);
            if m <= share {
                return s.ticks.clone().collect();
            }
            // share >= 2 points from the first tick to the last.
            (0..share)
                .map(|j| {
                    s.ticks.start
                        + (u128::from(j) * u128::from(m - 1) / u128::from(share - 1)) as u64
                })
                .collect()
        })
        .collect()
}

/// The first tick of the hold: the first whose sample is the path's end at rest, bit for bit
/// (t_k at or after the end of the motion; found in closed form, then a step or two).
fn hold_start(path: &TaskPath, ts: f64) -> u64 {
    let rest = path.sample(2.0 * path.duration() + 1.0);
    // The durations summed in the order `sample` sums them: the last segment's end.
    let mut k = first_tick_at(path.duration(), ts).saturating_sub(2);
    // Past the end the time law is clamped: the sample is the rest point within a few ticks.
    while !same_bits(&path.sample(k as f64 * ts), &rest) {
        k += 1;
    }
    k
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
    /// the motion plus `hold_s`. Fails, naming the point, if a reference point is unreachable or
    /// past the singularity margins. Once the path's time law has saturated (the hold, found in
    /// closed form) every sample is the same, so only the motion is checked tick by tick: a long
    /// hold costs nothing. A motion of more than [`MAX_CHECKED_TICKS`] ticks is checked at that
    /// many ([`checked_ticks`]): a config cannot make this take more than a fraction of a second.
    pub fn build(
        robot: &DeltaRobot,
        path: &TaskPath,
        ts: f64,
        hold_s: f64,
    ) -> Result<Self, KinematicsError> {
        let duration = path.duration();
        let n = ((duration + hold_s) / ts).round() as usize;
        let end = n as u64 + 2;
        let hold_from = hold_start(path, ts).min(end);
        let spans = path.spans(ts, hold_from);
        for (span, ticks) in spans.iter().zip(checked_ticks(&spans, MAX_CHECKED_TICKS)) {
            for k in ticks {
                let t = k as f64 * ts;
                checked_sample(robot, path.sample_in(span, t), t)?;
            }
        }
        let hold_from = hold_from as usize;
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

    /// The row of tick k (t_k = k·Ts), for any k ≤ N + 1, checked: a motion longer than
    /// [`MAX_CHECKED_TICKS`] was checked by `build` only at that many ticks, so the loop's
    /// reference (the supervisor's feed, the in-process loop) takes its rows from here and ends
    /// the run at the first that fails.
    pub fn try_row(&self, k: usize) -> Result<RefRow, KinematicsError> {
        let t = k as f64 * self.ts;
        if k >= self.hold_from {
            return Ok(RefRow { t, ..self.hold });
        }
        checked_row(&self.robot, &self.path, t)
    }

    /// The row of tick k, for views of ticks the loop already ran (their rows passed
    /// [`Self::try_row`]); a row that fails its check reads as the end point.
    pub fn row(&self, k: usize) -> RefRow {
        self.try_row(k).unwrap_or(RefRow {
            t: k as f64 * self.ts,
            ..self.hold
        })
    }

    /// Whether tick k lies in the hold, where every row is the same (but for its time).
    pub fn in_hold(&self, k: usize) -> bool {
        k >= self.hold_from
    }

    /// The number of rows, N + 2.
    pub fn row_count(&self) -> usize {
        self.n + 2
    }

    /// The joint rows a compensated law reads at tick k with a look-ahead of d ticks: k + d and
    /// k + d + 1, or past the last row (N + 1, the last the process modes' controller receives)
    /// that row.
    pub fn rows_ahead(&self, k: u64, d: u64) -> Result<(Reference, Reference), KinematicsError> {
        let last = self.row_count() as u64 - 1;
        let j = k.saturating_add(d).min(last);
        Ok((
            self.try_row(j as usize)?.joint,
            self.try_row((j + 1).min(last) as usize)?.joint,
        ))
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

    /// The spans give every tick to the segment `sample` gives it to, and the hold starts at the
    /// first tick whose sample is the end at rest (what walking every tick found).
    #[test]
    fn spans_and_hold_in_closed_form_equal_the_tick_walk() {
        let cfg = RunConfig::from_toml_str(
            "name = \"r\"\n[scenario]\npath = \"custom\"\nsegments = [\n{ from = [0.25, 0, -0.43], to = [0, 0.15, -0.43], apex_m = 0.12, duration_s = 0.1003 },\n{ from = [0, 0.15, -0.43], to = [-0.25, 0, -0.43], apex_m = 0.05, duration_s = 0.0004 },\n{ from = [-0.25, 0, -0.43], to = [0.1, 0, -0.4], apex_m = 0.0, duration_s = 0.07 }]\nhold_s = 0.01\n",
            None,
        )
        .unwrap();
        let paper = |p: &str| {
            let c = RunConfig::from_toml_str(&format!("[scenario]\npath = \"{p}\"\n"), None);
            (TaskPath::from_section(&c.unwrap().scenario), 3e-4)
        };
        let custom = TaskPath::from_section(&cfg.scenario);
        let cases = [3e-4, 1e-4, 7e-5].map(|ts| (custom.clone(), ts));
        for (path, ts) in cases.into_iter().chain(["s1", "s2", "s3"].map(paper)) {
            let r = JointReference::build(&DeltaRobot::default(), &path, ts, 0.01).unwrap();
            let end = r.row_count() as u64;
            let spans = path.spans(ts, end);
            assert_eq!(spans.first().unwrap().ticks.start, 0);
            assert_eq!(spans.last().unwrap().ticks.end, end);
            let rest = path.sample(10.0);
            for w in spans.windows(2) {
                assert_eq!(w[0].ticks.end, w[1].ticks.start);
            }
            for s in &spans {
                for k in s.ticks.clone() {
                    let t = k as f64 * ts;
                    assert!(
                        same_bits(&path.sample_in(s, t), &path.sample(t)),
                        "{ts} {k}"
                    );
                }
            }
            let first_rest = (0..end)
                .find(|&k| same_bits(&path.sample(k as f64 * ts), &rest))
                .unwrap() as usize;
            assert_eq!(r.hold_from, first_rest, "{ts}");
        }
    }

    /// Regression: a 3 KB config of 25 one-hour segments (300 M ticks) was checked tick by tick,
    /// hours before the run started. At most [`MAX_CHECKED_TICKS`] are checked (each segment's
    /// first and last among them), in well under a second.
    #[test]
    fn regression_hour_segments_were_checked_tick_by_tick() {
        let seg = "{ from = [0.25, 0, -0.43], to = [-0.25, 0, -0.43], apex_m = 0.12, duration_s = 3600.0 }";
        let text = format!(
            "name = \"long\"\n[scenario]\npath = \"custom\"\nsegments = [{}, {{ from = [-0.25, 0, -0.43], to = [0.25, 0, -0.43], apex_m = 0.1, duration_s = 0.2 }}]\n",
            vec![seg; 24].join(", ")
        );
        let cfg = RunConfig::from_toml_str(&text, None).unwrap();
        let path = TaskPath::from_section(&cfg.scenario);
        let t0 = std::time::Instant::now();
        let r = JointReference::build(&DeltaRobot::default(), &path, 3e-4, 0.0).unwrap();
        let took = t0.elapsed();
        assert!(r.n > 288_000_000, "{}", r.n);
        let spans = path.spans(3e-4, r.hold_from as u64);
        let picked = checked_ticks(&spans, MAX_CHECKED_TICKS);
        let total: usize = picked.iter().map(Vec::len).sum();
        assert!(total as u64 <= MAX_CHECKED_TICKS, "{total}");
        for (s, p) in spans.iter().zip(&picked) {
            assert_eq!(p.first(), Some(&s.ticks.start));
            assert_eq!(p.last(), Some(&(s.ticks.end - 1)));
        }
        // The short segment keeps every one of its ticks.
        let short = spans.last().unwrap().ticks.clone();
        assert!(short.end - short.start > 600, "{short:?}");
        assert_eq!(picked.last().unwrap().len() as u64, short.end - short.start);
        assert!(took.as_secs_f64() < 5.0, "{took:?}");
    }

    /// Regression: a motion longer than [`MAX_CHECKED_TICKS`] is checked by `build` at that many
    /// ticks, and a tick between them that failed its check read silently as the end point in
    /// the loop's reference. The loop takes its rows from `try_row`, which names the failure.
    #[test]
    fn regression_an_unchecked_tick_read_silently_as_the_end_point() {
        let text = "name = \"arch\"\n[scenario]\npath = \"custom\"\nsegments = [{ from = [0.25, 0, -0.43], to = [-0.25, 0, -0.43], apex_m = 0.9, duration_s = 1.0 }]\n";
        let cfg = RunConfig::from_toml_str(text, None).unwrap();
        let path = TaskPath::from_section(&cfg.scenario);
        let robot = DeltaRobot::default();
        let ts = 3e-4;
        assert!(JointReference::build(&robot, &path, ts, 0.0).is_err());
        // As `build` leaves it when the failing ticks were not among those it checked.
        let end = hold_start(&path, ts);
        let r = JointReference {
            ts,
            n: end as usize,
            duration: path.duration(),
            robot: robot.clone(),
            path: path.clone(),
            hold_from: end as usize,
            hold: checked_row(&robot, &path, end as f64 * ts).unwrap(),
        };
        let bad = (0..end as usize).find(|&k| r.try_row(k).is_err());
        assert!(bad.is_some_and(|k| k > 0), "{bad:?}");
        assert!(r.try_row(0).is_ok() && r.try_row(end as usize).is_ok());
    }
}
