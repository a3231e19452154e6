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

use crate::live::ReferenceTopics;
use crate::msg::{self, JointState};
use crate::node::{Participant, Settings, Waiting, Writer, reliable, wait_matched};
use anyhow::{Context, Result, bail};
use deltaloop_config::RunConfig;
use deltaloop_controller::process::Step;
use deltaloop_study::Study;
use deltaloop_transport::wire::{RefSample, StateMsg, TorqueMsg};
use rustdds::GUID;
use std::time::{Duration, Instant};

/// The node the robot's topics belong to.
pub const NODE: &str = "deltaloop_robot";

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
}

/// Judges one command against tick `k` (period `ts_ns`): τ (N m) if it answers tick k, else
/// None with the refusal counted under its cause in `refused`.
pub fn judge(m: &JointState, k: u64, ts_ns: u64, refused: &mut Refused) -> Option<[f64; 3]> {
    let named = m.name.is_empty() || m.name.iter().map(String::as_str).eq(msg::JOINTS);
    if !named {
        refused.names += 1;
        return None;
    }
    let Ok(tau) = <[f64; 3]>::try_from(m.effort.as_slice()) else {
        refused.length += 1;
        return None;
    };
    if !tau.iter().all(|t| t.is_finite()) {
        refused.non_finite += 1;
        return None;
    }
    if m.header.stamp.ns() != Some(k * ts_ns) {
        refused.stale += 1;
        return None;
    }
    Some(tau)
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
}

impl Robot {
    /// Joins the graph of the run's `[ros2]`, publishes `law`'s trajectory and waits for the
    /// node (a reader of the states and a writer of the commands, `[ros2] wait_s`).
    pub fn new(cfg: &RunConfig, law: &str) -> Result<Self> {
        let settings = Settings::of_run(cfg)?;
        let section = settings.section.clone();
        if let Some(w) = settings.warning() {
            eprintln!("{NODE}: {w}");
        }
        let study = Study::new(cfg.clone()).context("the scenario's reference")?;
        let ts_ns = cfg.ts_ns();
        let (state_topic, command_topic) =
            (section.state_topic.clone(), section.command_topic.clone());
        let domain = settings.domain;
        let part = Participant::join(settings.clone())?;
        let reference = ReferenceTopics::publish(&part, NODE, law, &study.reference, ts_ns, 10)?;
        let states: Writer<JointState> = part.writer(NODE, &state_topic, reliable(10))?;
        let commands = Waiting::new(part.reader(NODE, &command_topic, reliable(10))?)?;
        // The node is there when it reads the states and its commands reach us.
        let (read, heard) = wait_matched(
            &states,
            &commands.reader,
            Duration::from_secs_f64(section.wait_s),
        );
        if !(read && heard) {
            bail!(
                "no ROS 2 node {} within {} s (domain {domain}, {}): start the node first, or raise [ros2] wait_s",
                match (read, heard) {
                    (false, false) => format!("read {state_topic} or wrote {command_topic}"),
                    (true, false) => format!("wrote {command_topic}"),
                    _ => format!("read {state_topic}"),
                },
                section.wait_s,
                settings.reach()
            );
        }
        Ok(Self {
            _part: part,
            states,
            reference,
            commands,
            ts_ns,
            silence: Duration::from_millis(u64::from(cfg.loop_.silence_timeout_ms)),
            from: None,
            refused: Refused::default(),
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
                    self.refused.undecodable += 1;
                    continue;
                }
            };
            let w = s.sample_info().writer_guid();
            if *self.from.get_or_insert(w) != w {
                self.refused.second_publisher += 1;
                continue;
            }
            if let Some(t) = judge(s.value(), k, self.ts_ns, &mut self.refused) {
                answer.get_or_insert(t);
            }
        }
        answer
    }

    /// The count line of the end.
    fn summary(&self) -> String {
        let r = &self.refused;
        format!("{NODE}: {} command(s) refused: {r}", r.total())
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
                return Err(format!(
                    "the ROS 2 node did not answer tick {k} within {} ms",
                    self.silence.as_millis()
                ));
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
        let good = cmd(7 * ts, &msg::JOINTS, &[1.0, -2.0, 0.5]);
        assert_eq!(judge(&good, 7, ts, &mut r), Some([1.0, -2.0, 0.5]));
        let unnamed = cmd(7 * ts, &[], &[1.0, 2.0, 3.0]);
        assert_eq!(judge(&unnamed, 7, ts, &mut r), Some([1.0, 2.0, 3.0]));
        assert_eq!(r, Refused::default());
        judge(&cmd(6 * ts, &msg::JOINTS, &[0.0; 3]), 7, ts, &mut r);
        judge(&cmd(7 * ts + 1, &msg::JOINTS, &[0.0; 3]), 7, ts, &mut r);
        judge(
            &cmd(7 * ts, &["joint_1", "joint_3", "joint_2"], &[0.0; 3]),
            7,
            ts,
            &mut r,
        );
        judge(&cmd(7 * ts, &msg::JOINTS, &[0.0; 2]), 7, ts, &mut r);
        judge(
            &cmd(7 * ts, &msg::JOINTS, &[0.0, f64::NAN, 0.0]),
            7,
            ts,
            &mut r,
        );
        let mut neg = cmd(0, &msg::JOINTS, &[0.0; 3]);
        neg.header.stamp.sec = -1;
        judge(&neg, 0, ts, &mut r);
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
    let law = args.law.clone();
    deltaloop_transport::exit::exit(
        NODE,
        deltaloop_controller::process::serve(&args.run, &term, NODE, |cfg| Robot::new(cfg, &law)),
    )
}
