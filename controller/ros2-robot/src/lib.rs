//! `--controller ros2`: a ROS 2 node is the controller. This process takes the controller's
//! place in the run (the same handshake, reference ring and stamps as any controller process,
//! [`deltaloop_controller::process::serve`]) and is the robot's side of ros-controls'
//! topic-based hardware interface: each state goes out on `/robot_joint_states` (JointState: q,
//! q̇ as measured, `effort` τᵃ_k, stamp k·Ts) and the node's command for it comes back on
//! `/robot_joint_commands` (JointState, `effort` τ_k, the state's stamp).
//!
//! A command answers tick k if and only if its stamp is k·Ts. The process waits for it (up to
//! the silence limit) in both modes; in realtime the plant applies it by the arrival rule (its
//! latency felt and recorded, a late one dropped and counted). A command with other names, another
//! length, a non-finite torque, another tick's stamp, or from a second publisher is refused and
//! counted; the counts are the process's last line.

use anyhow::{Context, Result, bail};
use deltaloop_config::{LoopMode, RunConfig};
use deltaloop_controller::process::Step;
use deltaloop_ros2::live::ReferenceTopics;
use deltaloop_ros2::msg::{self, JointState};
use deltaloop_ros2::node::{
    Participant, ROBOT_NODE, Settings, Waiting, Writer, reliable, robot_waiting_line, wait_matched,
};
use deltaloop_study::Study;
use deltaloop_transport::wire::{RefSample, StateMsg, TorqueMsg};
use rustdds::GUID;
use std::time::{Duration, Instant};

/// Commands refused, by cause.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Refused {
    /// Joint names other than joint_1, joint_2, joint_3 (in that order).
    pub names: u64,
    /// `effort` not three values.
    pub length: u64,
    /// A NaN or infinite torque.
    pub non_finite: u64,
    /// A stamp of a tick already answered or given up (or not a tick at all).
    pub stale: u64,
    /// From a publisher other than the first one heard.
    pub second_publisher: u64,
    /// Not a JointState in plain CDR (another type, XCDR2, truncated).
    pub undecodable: u64,
}

/// Each cause's count, in one line: `1 joint names, 0 lengths, …`.
impl std::fmt::Display for Refused {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{} joint names, {} lengths, {} non-finite, {} stale, {} second publisher, {} undecodable",
            self.names,
            self.length,
            self.non_finite,
            self.stale,
            self.second_publisher,
            self.undecodable
        )
    }
}

impl Refused {
    pub fn total(&self) -> u64 {
        self.names
            + self.length
            + self.non_finite
            + self.stale
            + self.second_publisher
            + self.undecodable
    }

    /// Counts `r` under its cause.
    fn count(&mut self, r: Refusal) {
        *match r {
            Refusal::Names => &mut self.names,
            Refusal::Length => &mut self.length,
            Refusal::NonFinite => &mut self.non_finite,
            Refusal::Stale { .. } => &mut self.stale,
            Refusal::SecondPublisher => &mut self.second_publisher,
            Refusal::Undecodable => &mut self.undecodable,
        } += 1;
    }
}

/// Why one command was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Refusal {
    Names,
    Length,
    NonFinite,
    /// Its stamp (s, ns) is not the awaited tick's.
    Stale {
        sec: i32,
        nanosec: u32,
    },
    SecondPublisher,
    Undecodable,
}

impl std::fmt::Display for Refusal {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Names => write!(f, "joint names other than {}", msg::JOINTS.join(", ")),
            Self::Length => write!(f, "effort not three values"),
            Self::NonFinite => write!(f, "a NaN or infinite torque"),
            Self::Stale { sec, nanosec } => {
                write!(f, "stale, stamped {sec} s {nanosec} ns")
            }
            Self::SecondPublisher => write!(f, "from a second publisher"),
            Self::Undecodable => write!(f, "not a plain-CDR JointState"),
        }
    }
}

/// Judges one command against tick `k` (period `ts_ns`): τ (N m) if it answers tick k, else
/// why it is refused.
pub fn judge(m: &JointState, k: u64, ts_ns: u64) -> Result<[f64; 3], Refusal> {
    let named = m.name.is_empty() || m.name.iter().map(String::as_str).eq(msg::JOINTS);
    if !named {
        return Err(Refusal::Names);
    }
    let Ok(tau) = <[f64; 3]>::try_from(m.effort.as_slice()) else {
        return Err(Refusal::Length);
    };
    if !tau.iter().all(|t| t.is_finite()) {
        return Err(Refusal::NonFinite);
    }
    if m.header.stamp.ns() != Some(k * ts_ns) {
        return Err(Refusal::Stale {
            sec: m.header.stamp.sec,
            nanosec: m.header.stamp.nanosec,
        });
    }
    Ok(tau)
}

/// How long the robot waits for the answer to a tick: the silence limit, and in realtime no
/// longer than the plant waits (`[faults] controller_silence_ticks`), whose safe stop then ends
/// the run: the robot's end and its counts of refused commands reach the run's record.
fn give_up(cfg: &RunConfig, mode: LoopMode) -> Duration {
    let silence = Duration::from_millis(u64::from(cfg.loop_.silence_timeout_ms));
    match mode {
        LoopMode::Realtime => {
            let ticks = u64::from(cfg.faults.controller_silence_ticks);
            silence.min(Duration::from_nanos(ticks.saturating_mul(cfg.ts_ns())))
        }
        _ => silence,
    }
}

/// What the run calls this controller (its READY): `tdc (ros2)` in the tables.
const LABEL: &str = "ros2";

/// The robot's side of the DDS loop: a [`Step`] that asks the node.
pub struct Robot {
    _part: Participant,
    states: Writer<JointState>,
    reference: ReferenceTopics,
    commands: Waiting<JointState>,
    ts_ns: u64,
    silence: Duration,
    /// The first publisher heard on the command topic: the only one obeyed.
    from: Option<GUID>,
    pub refused: Refused,
    /// The first command refused while the current tick is awaited, and how many are.
    refused_now: (Option<Refusal>, u64),
}

impl Robot {
    /// Joins the graph of the run's `[ros2]`, publishes `law`'s trajectory and waits for the
    /// node (a reader of the states and a writer of the commands, `[ros2] wait_s`).
    pub fn new(cfg: &RunConfig, law: &str, mode: LoopMode) -> Result<Self> {
        let settings = Settings::of_run(cfg)?;
        let section = settings.section.clone();
        if let Some(w) = settings.warning() {
            eprintln!("{ROBOT_NODE}: {w}");
        }
        let study = Study::new(cfg.clone()).context("the scenario's reference")?;
        let ts_ns = cfg.ts_ns();
        let (state_topic, command_topic) =
            (section.state_topic.clone(), section.command_topic.clone());
        let domain = settings.domain;
        let part = Participant::join(settings.clone())?;
        let reference =
            ReferenceTopics::publish(&part, ROBOT_NODE, law, &study.reference, ts_ns, 10)?;
        let states: Writer<JointState> = part.writer(ROBOT_NODE, &state_topic, reliable(10))?;
        let commands = Waiting::new(part.reader(ROBOT_NODE, &command_topic, reliable(10))?)?;
        // The node is there when one participant reads the states and its commands reach us:
        // no tick 0 goes out before that.
        let wait = Duration::from_secs_f64(section.wait_s);
        eprintln!("{ROBOT_NODE}: {}", robot_waiting_line(&settings));
        let t0 = Instant::now();
        let m = wait_matched(&states, &commands.reader, wait);
        if m.pair().is_none() {
            let missing = match (m.readers.is_empty(), m.writers.is_empty()) {
                (true, true) => format!("read {state_topic} or wrote {command_topic}"),
                (false, true) => format!("wrote {command_topic}"),
                (true, false) => format!("read {state_topic}"),
                (false, false) => format!(
                    "both read {state_topic} and wrote {command_topic} (one participant read, another wrote)"
                ),
            };
            bail!(
                "no ROS 2 node {missing} within [ros2] wait_s = {} s (domain {domain}, {}): start the node within that time (the example node reads the run folder's config.toml), or raise wait_s (at most 25 s)",
                section.wait_s,
                settings.reach()
            );
        }
        eprintln!(
            "{ROBOT_NODE}: a ROS 2 node matched after {:.1} s",
            t0.elapsed().as_secs_f64()
        );
        Ok(Self {
            _part: part,
            states,
            reference,
            commands,
            ts_ns,
            silence: give_up(cfg, mode),
            from: None,
            refused: Refused::default(),
            refused_now: (None, 0),
        })
    }

    /// The commands taken now: the answer to tick `k`, if one came.
    fn take(&mut self, k: u64) -> Option<[f64; 3]> {
        let mut answer = None;
        // RustDDS moves past a sample it cannot decode; the bound only guards against an error
        // that would not move on.
        for _ in 0..4096 {
            let s = match self.commands.reader.take_next_sample() {
                Ok(Some(s)) => s,
                Ok(None) => break,
                Err(_) => {
                    self.refuse(Refusal::Undecodable);
                    continue;
                }
            };
            let w = s.sample_info().writer_guid();
            if *self.from.get_or_insert(w) != w {
                self.refuse(Refusal::SecondPublisher);
                continue;
            }
            match judge(s.value(), k, self.ts_ns) {
                Ok(t) => {
                    answer.get_or_insert(t);
                }
                Err(r) => self.refuse(r),
            }
        }
        answer
    }

    /// Counts `r`, and keeps it if it is the first while this tick is awaited.
    fn refuse(&mut self, r: Refusal) {
        self.refused.count(r);
        self.refused_now.0.get_or_insert(r);
        self.refused_now.1 += 1;
    }

    /// Why tick `k` went unanswered: the silence, and the commands refused meanwhile.
    fn unanswered(&self, k: u64) -> String {
        let ms = self.silence.as_millis();
        match self.refused_now {
            (Some(first), n) => format!(
                "the ROS 2 node did not answer tick {k} within {ms} ms: its {n} command(s) meanwhile were refused, the first: {first} (tick {k} is at {} ns)",
                k * self.ts_ns
            ),
            (None, _) => format!("the ROS 2 node did not answer tick {k} within {ms} ms"),
        }
    }

    /// The count line of the end.
    fn summary(&self) -> String {
        let r = &self.refused;
        format!("{ROBOT_NODE}: {} command(s) refused: {r}", r.total())
    }
}

impl Step for Robot {
    /// Publishes the state (and the reference row) and waits for the node's command for it: in
    /// lockstep and in realtime alike, up to the silence limit. In realtime the plant judges it by
    /// its arrival (late: dropped and counted); meanwhile newer states queue and the newest is
    /// answered next, the others skipped. The node sees exactly the states it answers, as the
    /// built-in controller does: the run replays.
    fn step(&mut self, state: &StateMsg, row: &RefSample) -> Result<TorqueMsg, String> {
        let k = state.tick;
        let t_ns = k * self.ts_ns;
        let _ = self.reference.write(t_ns, &row.q, &row.qd);
        let js = msg::joint_state(t_ns, &state.q, &state.qd, &state.tau_applied);
        if let Err(e) = self.states.write(js, None) {
            return Err(format!("cannot publish the state of tick {k}: {e:?}"));
        }
        let until = Instant::now() + self.silence;
        self.refused_now = (None, 0);
        loop {
            if let Some(tau) = self.take(k) {
                return Ok(TorqueMsg {
                    tick: k,
                    tau,
                    ..TorqueMsg::default()
                });
            }
            let now = Instant::now();
            if now >= until {
                return Err(self.unanswered(k));
            }
            self.commands
                .wait((until - now).min(Duration::from_millis(50)));
        }
    }

    fn label(&self) -> Option<&str> {
        Some(LABEL)
    }

    fn refused(&self) -> Option<(u64, String)> {
        Some((self.refused.total(), self.refused.to_string()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// In realtime the robot gives up with the plant (its refusals then reach the record); in
    /// lockstep, where the plant waits as long, at the silence limit.
    #[test]
    fn the_robot_waits_no_longer_than_the_plant() {
        let mut cfg = RunConfig::from_toml_str(
            &std::fs::read_to_string(concat!(
                env!("CARGO_MANIFEST_DIR"),
                "/../../configs/s1-ros2.toml"
            ))
            .unwrap(),
            None,
        )
        .unwrap();
        cfg.faults.controller_silence_ticks = 500;
        assert_eq!(
            give_up(&cfg, LoopMode::Realtime),
            Duration::from_millis(500)
        );
        assert_eq!(
            give_up(&cfg, LoopMode::Lockstep),
            Duration::from_millis(2000)
        );
        cfg.faults.controller_silence_ticks = 5000;
        assert_eq!(
            give_up(&cfg, LoopMode::Realtime),
            Duration::from_millis(2000)
        );
    }

    fn cmd(stamp_ns: u64, names: &[&str], effort: &[f64]) -> JointState {
        let mut m = msg::joint_state(stamp_ns, &[], &[], effort);
        m.name = names.iter().map(|s| s.to_string()).collect();
        m
    }

    /// Only the tick's own stamp, the three joints and finite torques answer; each refusal is
    /// counted under its cause.
    #[test]
    fn a_command_answers_its_tick_only() {
        let ts = 300_000;
        let mut r = Refused::default();
        let mut judged = |m: &JointState, k| judge(m, k, ts).inspect_err(|e| r.count(*e));
        let good = cmd(7 * ts, &msg::JOINTS, &[1.0, -2.0, 0.5]);
        assert_eq!(judged(&good, 7), Ok([1.0, -2.0, 0.5]));
        let unnamed = cmd(7 * ts, &[], &[1.0, 2.0, 3.0]);
        assert_eq!(judged(&unnamed, 7), Ok([1.0, 2.0, 3.0]));
        let stale = judged(&cmd(6 * ts, &msg::JOINTS, &[0.0; 3]), 7).unwrap_err();
        assert_eq!(stale.to_string(), "stale, stamped 0 s 1800000 ns");
        let _ = judged(&cmd(7 * ts + 1, &msg::JOINTS, &[0.0; 3]), 7);
        let swapped = cmd(7 * ts, &["joint_1", "joint_3", "joint_2"], &[0.0; 3]);
        assert_eq!(judged(&swapped, 7), Err(Refusal::Names));
        assert_eq!(
            judged(&cmd(7 * ts, &msg::JOINTS, &[0.0; 2]), 7),
            Err(Refusal::Length)
        );
        let nan = cmd(7 * ts, &msg::JOINTS, &[0.0, f64::NAN, 0.0]);
        assert_eq!(judged(&nan, 7), Err(Refusal::NonFinite));
        let mut neg = cmd(0, &msg::JOINTS, &[0.0; 3]);
        neg.header.stamp.sec = -1;
        let _ = judged(&neg, 0);
        assert_eq!(
            r,
            Refused {
                names: 1,
                length: 1,
                non_finite: 1,
                stale: 3,
                second_publisher: 0,
                undecodable: 0,
            }
        );
    }
}

impl Drop for Robot {
    fn drop(&mut self) {
        eprintln!("{}", self.summary());
    }
}

/// The arguments a controller process gets from `deltaloop run`.
#[derive(clap::Parser, Debug)]
#[command(
    name = "deltaloop-ros2-robot",
    about = "the robot's side of a ROS 2 controller node (started by `deltaloop run --controller ros2`)"
)]
struct Args {
    #[command(flatten)]
    run: deltaloop_transport::args::LoopArgs,
    /// The law the run is labelled with (the node computes it).
    #[arg(long, default_value = "")]
    law: String,
}

/// Entry point of `deltaloop-ros2-robot`.
pub fn main() -> std::process::ExitCode {
    use clap::Parser as _;
    let args = Args::parse();
    let term = deltaloop_transport::rt::child_signals();
    let (law, mode) = (args.law.clone(), args.run.mode);
    deltaloop_transport::exit::exit(
        ROBOT_NODE,
        deltaloop_controller::process::serve(
            &args.run,
            &term,
            ROBOT_NODE,
            deltaloop_link::Handoff::default(),
            |cfg| Robot::new(cfg, &law, mode),
        ),
    )
}
