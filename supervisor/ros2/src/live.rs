//! A run seen from ROS 2 while it runs (`run --ros2`): each law's finished ticks, as the run
//! records them, on `/<namespace>/<law>/joint_states` and `reference` (unless the robot of
//! `--controller ros2` publishes it), the platform's pose on
//! `/tf`, the simulated time on `/clock`, the loop's health on `/diagnostics` once a second, and
//! the run's events on `/rosout`.
//!
//! Off the loop: the supervisor publishes from its recorder (every `[ros2] every`-th tick), and
//! a writer never blocks (a full send window drops the sample and counts it).

use crate::msg::{
    self, BASE_FRAME, Clock, DiagnosticArray, DiagnosticStatus, Header, JointState,
    JointTrajectory, JointTrajectoryPoint, KeyValue, Log, Quaternion, TfMessage, Time, Transform,
    TransformStamped, Vector3,
};
use crate::node::{Participant, Settings, Writer, best_effort, latched, reliable};
use anyhow::Result;
use deltaloop_config::Law;
use deltaloop_model::{DeltaRobot, Vec3};
use deltaloop_study::record::{ReplyFate, TickRecord, TickSink};
use deltaloop_study::reference::{JointReference, RefRow};
use rustdds::RTPSEntity;
use std::sync::{Arc, Mutex};
use std::time::Instant;

/// The node the live topics belong to.
pub const NODE: &str = "deltaloop";

/// The most points a law's `trajectory` carries (5 minutes of motion at 3.3 kHz): the hold after
/// the motion is its last point.
pub const MAX_TRAJECTORY_POINTS: usize = 1_000_000;

/// The topics every law shares, and the participant.
pub struct LiveRun {
    part: Participant,
    tf: Mutex<Writer<TfMessage>>,
    clock: Mutex<Writer<Clock>>,
    diagnostics: Mutex<Writer<DiagnosticArray>>,
    rosout: Mutex<Writer<Log>>,
    robot: DeltaRobot,
    ts_ns: u64,
}

impl LiveRun {
    /// Joins the ROS 2 graph of `settings` for a run of period `ts_ns` (ns) on `robot`.
    pub fn open(settings: Settings, robot: DeltaRobot, ts_ns: u64) -> Result<Arc<Self>> {
        let part = Participant::join(settings)?;
        Ok(Arc::new(Self {
            tf: Mutex::new(part.writer(NODE, "/tf", reliable(100))?),
            clock: Mutex::new(part.writer(NODE, "/clock", best_effort(1))?),
            diagnostics: Mutex::new(part.writer(NODE, "/diagnostics", reliable(10))?),
            rosout: Mutex::new(part.writer(NODE, "/rosout", latched(1000))?),
            part,
            robot,
            ts_ns,
        }))
    }

    /// A line on `/rosout` at `level` (rcl_interfaces/Log's: INFO 20, …), stamped with simulated
    /// `t_ns`.
    pub fn log(&self, level: u8, t_ns: u64, text: &str) {
        let m = Log {
            stamp: Time::of_ns(t_ns),
            level,
            name: NODE.into(),
            msg: text.into(),
            file: String::new(),
            function: String::new(),
            line: 0,
        };
        let _ = lock(&self.rosout).write(m, None);
    }

    /// The sink of `law`'s ticks: its topics made, its trajectory published. `reference`: None
    /// when another node publishes the law's `reference` and `trajectory` (the robot of
    /// `--controller ros2`), so that those topics have one writer.
    pub fn law(
        self: &Arc<Self>,
        law: Law,
        reference: Option<&JointReference>,
    ) -> Result<LawTopics> {
        let s = &self.part.settings;
        let name = law.to_string();
        let reference = reference
            .map(|r| ReferenceTopics::publish(&self.part, NODE, &name, r, self.ts_ns, 100))
            .transpose()?;
        self.log(msg::INFO, 0, &format!("{law}: started"));
        Ok(LawTopics {
            joints: self
                .part
                .writer(NODE, &s.law_topic(&name, "joint_states"), reliable(100))?,
            reference,
            frame: format!("{}/end_effector", name.replace('-', "_")),
            status_name: format!("{}/{}", s.section.namespace, name.replace('-', "_")),
            every: u64::from(s.section.every.max(1)),
            run: Arc::clone(self),
            law,
            health: Health::new(),
            last_k: 0,
            dropped: 0,
        })
    }
}

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

/// The reference as one JointTrajectory: point k at k·Ts, through the first tick of the hold
/// (every later row equals it), at most [`MAX_TRAJECTORY_POINTS`].
pub fn trajectory_of(reference: &JointReference, ts_ns: u64) -> JointTrajectory {
    let n = reference.row_count().min(MAX_TRAJECTORY_POINTS);
    let last = (0..n).find(|k| reference.in_hold(*k)).unwrap_or(n - 1);
    JointTrajectory {
        header: Header {
            stamp: Time::default(),
            frame_id: BASE_FRAME.into(),
        },
        joint_names: msg::JOINTS.map(String::from).to_vec(),
        points: (0..=last)
            .map(|k| {
                let j = reference.row(k).joint;
                JointTrajectoryPoint {
                    positions: j.q.as_slice().to_vec(),
                    velocities: j.qd.as_slice().to_vec(),
                    accelerations: j.qdd.as_slice().to_vec(),
                    effort: Vec::new(),
                    time_from_start: Time::of_ns(k as u64 * ts_ns),
                }
            })
            .collect(),
    }
}

/// The loop's health over the last second of wall time, for `/diagnostics`: from the first
/// tick it counts (not from when the law's topics were made).
struct Health {
    /// When its first tick came; None before it.
    since: Option<Instant>,
    first_k: u64,
    ticks: u64,
    /// Ticks whose reply was not applied (late, skipped, missed): the drives held.
    misses: u64,
    /// A_k − t_k of the applied commands, µs.
    arrival_us: hdrhistogram::Histogram<u64>,
}

impl Health {
    fn new() -> Self {
        Self {
            since: None,
            first_k: 0,
            ticks: 0,
            misses: 0,
            arrival_us: hdrhistogram::Histogram::new_with_bounds(1, 60_000_000, 3)
                .expect("static bounds"),
        }
    }

    /// Counts tick k (`missed`: its reply was not applied; `arrival_ns`: A_k − t_k).
    fn count(&mut self, k: u64, missed: bool, arrival_ns: Option<u64>) {
        if self.since.is_none() {
            self.since = Some(Instant::now());
            self.first_k = k;
        }
        self.ticks += 1;
        self.misses += u64::from(missed);
        if let Some(a) = arrival_ns {
            let _ = self.arrival_us.record((a / 1000).max(1));
        }
    }

    /// Whether a second of wall time has passed since its first tick.
    fn second_over(&self) -> bool {
        self.since.is_some_and(|t| t.elapsed().as_secs() >= 1)
    }

    /// Starts over (the next interval).
    fn reset(&mut self) {
        self.since = None;
        self.ticks = 0;
        self.misses = 0;
        self.arrival_us.reset();
    }
}

/// A law's `reference` (per tick) and `trajectory` (all of it, latched): the run's node writes
/// them, or the robot's with `--controller ros2`.
pub struct ReferenceTopics {
    states: Writer<JointState>,
    trajectory: Writer<JointTrajectory>,
}

impl ReferenceTopics {
    /// `law`'s two topics for `node`, the trajectory published (`depth`: the per-tick topic's
    /// send window).
    pub fn publish(
        part: &Participant,
        node: &str,
        law: &str,
        reference: &JointReference,
        ts_ns: u64,
        depth: i32,
    ) -> Result<Self> {
        let s = &part.settings;
        let trajectory: Writer<JointTrajectory> =
            part.writer(node, &s.law_topic(law, "trajectory"), latched(1))?;
        trajectory
            .write(trajectory_of(reference, ts_ns), None)
            .map_err(|e| anyhow::anyhow!("cannot publish the trajectory: {e:?}"))?;
        let states = part.writer(node, &s.law_topic(law, "reference"), reliable(depth))?;
        Ok(Self { states, trajectory })
    }

    /// The reference at `t_ns` (ns of simulated time): q rad, q̇ rad/s. Whether it went out (a
    /// full send window drops it).
    pub fn write(&self, t_ns: u64, q: &[f64; 3], qd: &[f64; 3]) -> bool {
        let m = msg::joint_state(t_ns, q, qd, &[]);
        self.states.write(m, None).is_ok()
    }

    fn guids(&self) -> [rustdds::GUID; 2] {
        [self.states.guid(), self.trajectory.guid()]
    }
}

/// One law's topics: a [`TickSink`] of the run's recorder.
pub struct LawTopics {
    run: Arc<LiveRun>,
    law: Law,
    joints: Writer<JointState>,
    reference: Option<ReferenceTopics>,
    /// The `/tf` child frame: `<law>/end_effector`.
    frame: String,
    /// The `/diagnostics` status: `<namespace>/<law>`.
    status_name: String,
    every: u64,
    health: Health,
    last_k: u64,
    /// Samples a full send window dropped.
    dropped: u64,
}

impl LawTopics {
    fn publish(&mut self, r: &TickRecord, row: &RefRow) {
        let k = r.sample.k;
        let t_ns = k * self.run.ts_ns;
        let arr = |v: &Vec3| [v[0], v[1], v[2]];
        let (q, qd, tau) = (arr(&r.q_true), arr(&r.qd_true), arr(&r.sample.tau_applied));
        let mut ok = self
            .joints
            .write(msg::joint_state(t_ns, &q, &qd, &tau), None)
            .is_ok();
        if let Some(rt) = &self.reference {
            ok &= rt.write(t_ns, &arr(&row.joint.q), &arr(&row.joint.qd));
        }
        if let Ok(x) = self.run.robot.fk(&r.q_true) {
            let tf = TransformStamped {
                header: Header {
                    stamp: Time::of_ns(t_ns),
                    frame_id: BASE_FRAME.into(),
                },
                child_frame_id: self.frame.clone(),
                transform: Transform {
                    translation: Vector3 {
                        x: x[0],
                        y: x[1],
                        z: x[2],
                    },
                    rotation: Quaternion {
                        x: 0.0,
                        y: 0.0,
                        z: 0.0,
                        w: 1.0,
                    },
                },
            };
            let m = TfMessage {
                transforms: vec![tf],
            };
            ok &= lock(&self.run.tf).write(m, None).is_ok();
        }
        let clock = Clock {
            clock: Time::of_ns(t_ns),
        };
        let _ = lock(&self.run.clock).write(clock, None); // best effort: never refused
        if !ok {
            self.dropped += 1;
        }
    }

    /// One `/diagnostics` status of the ticks counted since the last one, the last of them
    /// `k`: WARN if any of them missed, else OK.
    fn diagnose(&mut self, k: u64) {
        let h = &mut self.health;
        let wall = h.since.map_or(0.0, |t| t.elapsed().as_secs_f64());
        let sim = (k + 1).saturating_sub(h.first_k) as f64 * self.run.ts_ns as f64 * 1e-9;
        let q = |p: f64| h.arrival_us.value_at_quantile(p).to_string();
        let values = [
            ("ticks", h.ticks.to_string()),
            ("misses", h.misses.to_string()),
            ("arrival_p50_us", q(0.5)),
            ("arrival_p99_9_us", q(0.999)),
            ("real_time_factor", format!("{:.3}", sim / wall.max(1e-9))),
            ("dropped_samples", self.dropped.to_string()),
        ];
        let level = if h.misses > 0 { WARN } else { OK };
        let status = DiagnosticStatus {
            level,
            name: self.status_name.clone(),
            message: format!("{} misses in {} ticks", h.misses, h.ticks),
            hardware_id: NODE.into(),
            values: values
                .into_iter()
                .map(|(k, v)| KeyValue {
                    key: k.into(),
                    value: v,
                })
                .collect(),
        };
        let m = DiagnosticArray {
            header: Header {
                stamp: Time::of_ns(k * self.run.ts_ns),
                frame_id: String::new(),
            },
            status: vec![status],
        };
        let _ = lock(&self.run.diagnostics).write(m, None);
        h.reset();
    }
}

/// diagnostic_msgs/DiagnosticStatus levels.
const OK: u8 = 0;
const WARN: u8 = 1;

/// Live: each tick as soon as it is recorded, not [`deltaloop_study::record::OPEN_TICKS`]
/// later when it is final (what it publishes does not change after).
impl TickSink for LawTopics {
    fn take(&mut self, _r: &TickRecord, _row: &RefRow, _n_true: Option<Vec3>) {}

    fn recorded(&mut self, r: &TickRecord, row: &RefRow) {
        let k = r.sample.k;
        self.last_k = k;
        self.health
            .count(k, r.fate != ReplyFate::Applied, r.arrival_ns);
        if k.is_multiple_of(self.every) {
            self.publish(r, row);
        }
        if self.health.second_over() {
            self.diagnose(k);
        }
    }
}

impl Drop for LawTopics {
    fn drop(&mut self) {
        // The ticks of the last (part of a) second.
        if self.health.ticks > 0 {
            self.diagnose(self.last_k);
        }
        let mut mine = vec![self.joints.guid()];
        if let Some(rt) = &self.reference {
            mine.extend(rt.guids());
        }
        if let Err(e) = self.run.part.retire(&mine) {
            eprintln!("ROS 2: {e:#}");
        }
        let t_ns = self.last_k * self.run.ts_ns;
        self.run.log(
            msg::INFO,
            t_ns,
            &format!(
                "{}: ended at tick {}{}",
                self.law,
                self.last_k,
                if self.dropped > 0 {
                    format!(" ({} samples dropped: a reader fell behind)", self.dropped)
                } else {
                    String::new()
                }
            ),
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use deltaloop_config::RunConfig;
    use deltaloop_study::Study;

    /// With `--controller ros2` the robot writes the law's reference topics, so the run's node
    /// writes only the law's joint_states (one writer per topic); otherwise all three. A law's
    /// writers leave the graph when it ends.
    #[test]
    fn a_law_leaves_its_reference_to_the_robot() {
        let live = LiveRun::open(Settings::localhost(227), DeltaRobot::default(), 300_000).unwrap();
        let writers = || live.part.announced(NODE).1.len();
        let run_wide = writers();
        let topics = live.law(Law::Tdc, None).unwrap();
        assert_eq!(writers(), run_wide + 1);
        drop(topics);
        assert_eq!(writers(), run_wide);
        let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../../configs/s1-nominal.toml");
        let study = Study::new(RunConfig::from_file(path.as_ref()).unwrap()).unwrap();
        let topics = live.law(Law::Tdc, Some(&study.reference)).unwrap();
        assert_eq!(writers(), run_wide + 3);
        drop(topics);
        assert_eq!(writers(), run_wide);
    }
}
