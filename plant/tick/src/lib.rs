//! The plant's side of one tick, written once and called by every loop mode (inproc, lockstep,
//! realtime, the loop benchmark): measure and publish state k, take what arrived for tick k (a
//! reply, or nothing), let the drives apply or hold, integrate [t_k, t_{k+1}), and say what
//! happened in the tick's telemetry. Transport code only moves these messages and stamps times.

mod reply;

pub use reply::{Arrival, ReplyFate, ReplyOutcome};

use deltaloop_config::RunConfig;
use deltaloop_config::TorqueLimit;
use deltaloop_model::sensor::{Sensor, SensorConfig};
use deltaloop_model::{
    DeltaRobot, KinematicsError, PayloadStep, Plant, PlantSample, SimConfig, Vec3,
};
use deltaloop_wire::{self as wire, StateMsg, TelemetryMsg};

/// The plant's simulation settings for a config (one mapping for every mode).
pub fn sim_config(cfg: &RunConfig) -> SimConfig {
    SimConfig {
        ts: cfg.loop_.ts_s,
        substeps: cfg.plant.substeps,
        friction: cfg.plant.friction,
        check_margins: true,
        payload_step: cfg.payload_step_tick().map(|tick| PayloadStep {
            mass_kg: cfg.plant.payload_step_kg,
            tick,
        }),
    }
}

/// The plant a config describes, at rest at `q0` (rad): dynamics, drives (clamp or reject,
/// transport delay) and sensors.
pub fn plant_from_config(cfg: &RunConfig, q0: Vec3) -> Result<Plant, KinematicsError> {
    let plant = Plant::new(
        DeltaRobot::default(),
        sim_config(cfg),
        cfg.plant.tau_max_nm,
        cfg.transport_delay_ns(),
        q0,
    )?
    .reject_over_limit(cfg.faults.torque_limit == TorqueLimit::Reject);
    let se = &cfg.sensor;
    Ok(if se.is_ideal() {
        plant
    } else {
        plant.with_sensor(Sensor::new(SensorConfig {
            encoder_counts_per_rev: se.encoder_counts_per_rev,
            q_noise_std: se.q_noise_std_rad,
            qd_noise_std: se.qd_noise_std_rad_s,
            seed: se.seed,
        }))
    })
}

/// What the drives did in one interval (the tick's telemetry flags).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Drives {
    /// A command was clamped to ±τ_max.
    pub clamped: bool,
    /// No command took effect: the drives held the last torque.
    pub held: bool,
    /// A command beyond ±τ_max was rejected.
    pub rejected: bool,
}

/// The physical plant under a [`PlantSide`]: the project's model ([`Plant`]), or another one
/// that answers the same questions (a model or a rig's drives in C, through the C ABI). Errors
/// are one line saying why the plant cannot go on.
pub trait Physics {
    /// The current tick k (the state is at t_k = k·Ts).
    fn tick(&self) -> u64;
    /// The true state at tick k: q (rad), q̇ (rad/s), τᵃ_k (N m), joint space; or why the plant
    /// cannot say (a foreign plant's error: the loop stops with a plant error).
    fn sample(&self) -> Result<PlantSample, String>;
    /// What the encoders report at tick k ([`Physics::sample`] through the sensors), or why they
    /// cannot. Called once per published state: it may advance a noise stream.
    fn measure(&mut self) -> Result<PlantSample, String>;
    /// Takes tick k's command (None: none arrived) reaching the drives `latency_ns` after t_k
    /// (plus the configured transport delay), and runs [t_k, t_{k+1}).
    fn advance_after(&mut self, cmd: Option<Vec3>, latency_ns: u64) -> Result<Drives, String>;
    /// One tick of safe stop: the drives brake with τ = G(q) − D q̇ (D = `damping`, N m s/rad).
    fn brake_tick(&mut self, damping: f64) -> Result<(), String>;
}

impl Physics for Plant {
    fn tick(&self) -> u64 {
        self.sim().tick()
    }
    fn sample(&self) -> Result<PlantSample, String> {
        Ok(Plant::sample(self))
    }
    fn measure(&mut self) -> Result<PlantSample, String> {
        Ok(Plant::measure(self))
    }
    fn advance_after(&mut self, cmd: Option<Vec3>, latency_ns: u64) -> Result<Drives, String> {
        let a = Plant::advance_after(self, cmd, latency_ns).map_err(|e| e.to_string())?;
        Ok(Drives {
            clamped: a.clamped,
            held: a.held,
            rejected: a.rejected,
        })
    }
    fn brake_tick(&mut self, damping: f64) -> Result<(), String> {
        Plant::brake_tick(self, damping)
            .map(|_| ())
            .map_err(|e| e.to_string())
    }
}

/// Why the plant side ends the loop.
#[derive(Clone, Debug, PartialEq)]
pub enum PlantStop {
    /// The controller missed `controller_silence_ticks` ticks in a row: a safe stop follows.
    ControllerSilent { tick: u64, cause: String },
    /// The model failed at `tick` (left the workspace, non-finite state): no safe stop possible.
    /// `tel` is the failed interval's telemetry as far as it goes (the reply's arrival, misses;
    /// no drive flags): every mode records it, so a run that diverged replays byte for byte.
    Diverged {
        tick: u64,
        cause: String,
        tel: Box<TelemetryMsg>,
    },
    /// The plant itself reported an error at `tick` (a foreign plant's truth or sensors failed):
    /// not the law's divergence; the loop stops there and a safe stop is tried.
    PlantError { tick: u64, cause: String },
}

impl PlantStop {
    /// The tick at which the loop stopped.
    pub fn tick(&self) -> u64 {
        match self {
            PlantStop::ControllerSilent { tick, .. }
            | PlantStop::Diverged { tick, .. }
            | PlantStop::PlantError { tick, .. } => *tick,
        }
    }

    /// The telemetry of the interval the model failed in (None for a silence stop).
    pub fn failed_interval(&self) -> Option<&TelemetryMsg> {
        match self {
            PlantStop::Diverged { tel, .. } => Some(tel),
            PlantStop::ControllerSilent { .. } | PlantStop::PlantError { .. } => None,
        }
    }

    /// One line saying why.
    pub fn cause(&self) -> &str {
        match self {
            PlantStop::ControllerSilent { cause, .. }
            | PlantStop::Diverged { cause, .. }
            | PlantStop::PlantError { cause, .. } => cause,
        }
    }
}

/// The plant side of the loop: the plant (the project's model unless another [`Physics`] is
/// given), its counters, and the run's last tick N.
#[derive(Clone, Debug)]
pub struct PlantSide<P = Plant> {
    plant: P,
    /// N: the last tick that gets a command; the plant then publishes tick N + 1 as final.
    last_tick: u64,
    ts_s: f64,
    /// The configured transport delay D, ns.
    delay_ns: u64,
    silence_ticks: u64,
    misses: u64,
    late: u64,
    consecutive: u64,
}

impl PlantSide {
    /// The plant of `cfg` at rest at `q0` (rad), for a run of ticks 0..=`last_tick`.
    pub fn from_config(cfg: &RunConfig, q0: Vec3, last_tick: u64) -> Result<Self, KinematicsError> {
        Ok(PlantSide::new(plant_from_config(cfg, q0)?, cfg, last_tick))
    }

    /// State k of the project's model, which always has one (see [`PlantSide::try_state`]).
    pub fn state(&mut self) -> StateMsg {
        let truth = self.plant.sample();
        let s = self.plant.measure();
        self.state_of(&truth, &s)
    }
}

impl<P: Physics> PlantSide<P> {
    /// `plant` run by the loop settings of `cfg`, for ticks 0..=`last_tick`.
    pub fn new(plant: P, cfg: &RunConfig, last_tick: u64) -> Self {
        Self {
            plant,
            last_tick,
            ts_s: cfg.loop_.ts_s,
            delay_ns: cfg.transport_delay_ns(),
            silence_ticks: u64::from(cfg.faults.controller_silence_ticks),
            misses: 0,
            late: 0,
            consecutive: 0,
        }
    }

    /// The current tick k (the plant's state is at t_k = k·Ts).
    pub fn tick(&self) -> u64 {
        self.plant.tick()
    }

    /// The plant itself (model, drives, sensors).
    pub fn plant(&self) -> &P {
        &self.plant
    }

    /// State k as the plant publishes it: measured q (rad) and q̇ (rad/s) through the sensor
    /// model, τᵃ_k (N m), and the noise-free truth; `STATE_FINAL` at k = N + 1. Times are left
    /// zero for the transport to stamp. Call once per tick: it advances the sensor's noise stream.
    /// A plant that cannot say its truth or measure stops the loop at k ([`PlantStop::PlantError`]):
    /// zeros in its place would be taken for the robot's state.
    pub fn try_state(&mut self) -> Result<StateMsg, PlantStop> {
        let k = self.tick();
        let stop = |what: &str, e: String| PlantStop::PlantError {
            tick: k,
            cause: format!("the plant's {what} failed at tick {k}: {e}"),
        };
        let truth = self.plant.sample().map_err(|e| stop("truth", e))?;
        let s = self.plant.measure().map_err(|e| stop("measure", e))?;
        Ok(self.state_of(&truth, &s))
    }

    /// The state message of measurement `s` and truth `truth`.
    fn state_of(&self, truth: &PlantSample, s: &PlantSample) -> StateMsg {
        StateMsg {
            tick: s.k,
            flags: if s.k > self.last_tick {
                wire::STATE_FINAL
            } else {
                0
            },
            q: s.q.into(),
            qd: s.qd.into(),
            tau_applied: s.tau_applied.into(),
            q_true: truth.q.into(),
            qd_true: truth.qd.into(),
            ..StateMsg::default()
        }
    }

    /// The state that ends a run early, numbered `tick`: the plant's true state (no sensor noise,
    /// and the noise stream is not advanced; zeros if the plant cannot say it) with
    /// `STATE_FINAL`, which releases the controller.
    pub fn final_state(&self, tick: u64) -> StateMsg {
        let s = self.plant.sample().unwrap_or(PlantSample {
            k: tick,
            q: Vec3::zeros(),
            qd: Vec3::zeros(),
            tau_applied: Vec3::zeros(),
        });
        StateMsg {
            tick,
            flags: wire::STATE_FINAL,
            q: s.q.into(),
            qd: s.qd.into(),
            tau_applied: s.tau_applied.into(),
            q_true: s.q.into(),
            qd_true: s.qd.into(),
            ..StateMsg::default()
        }
    }

    /// Counts a reply that came too late to be applied (realtime).
    pub fn late_reply(&mut self) {
        self.late += 1;
    }

    /// Takes what arrived for the current tick k and integrates [t_k, t_{k+1}). Returns the tick's
    /// telemetry (times left zero for the transport), or why the loop must stop.
    pub fn advance(&mut self, arrival: Arrival) -> Result<TelemetryMsg, PlantStop> {
        let k = self.tick();
        let mut tel = TelemetryMsg {
            tick: k,
            ..TelemetryMsg::default()
        };
        let (cmd, latency_ns) = match arrival.reply() {
            Some((t, latency)) => {
                self.consecutive = 0;
                // Saturating: a latency from a peer or a file must not wrap the time around.
                tel.arrival_ns = self.delay_ns.saturating_add(latency);
                (Some(Vec3::from(t.tau)), latency)
            }
            None => {
                self.misses += 1;
                self.consecutive += 1;
                tel.flags |= wire::TEL_MISSED;
                if self.consecutive >= self.silence_ticks {
                    return Err(PlantStop::ControllerSilent {
                        tick: k,
                        cause: format!(
                            "no torque within the budget for {} consecutive ticks ({:.1} ms; controller dead, stalled or too slow, {} late replies dropped); the plant held the last applied torque through them",
                            self.consecutive,
                            self.consecutive as f64 * self.ts_s * 1e3,
                            self.late
                        ),
                    });
                }
                (None, 0)
            }
        };
        tel.misses = self.misses;
        tel.late_dropped = self.late;
        let a = self
            .plant
            .advance_after(cmd, latency_ns)
            .map_err(|cause| PlantStop::Diverged {
                tick: k + 1,
                cause,
                tel: Box::new(tel),
            })?;
        tel.flags |= if a.clamped { wire::TEL_CLAMPED } else { 0 }
            | if a.held { wire::TEL_HELD } else { 0 }
            | if a.rejected { wire::TEL_REJECTED } else { 0 };
        Ok(tel)
    }

    /// One tick of safe stop: the drives brake with τ = G(q) − D q̇ (D = `damping`, N m s/rad),
    /// no controller. Returns the telemetry of the braked interval, numbered `tick`.
    pub fn brake(&mut self, tick: u64, damping: f64) -> Result<TelemetryMsg, String> {
        self.plant.brake_tick(damping)?;
        Ok(TelemetryMsg {
            tick,
            flags: wire::TEL_SAFE_STOP | wire::TEL_HELD,
            misses: self.misses,
            late_dropped: self.late,
            ..TelemetryMsg::default()
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use deltaloop_wire::TorqueMsg;

    fn side(silence: u32) -> PlantSide {
        let mut cfg = RunConfig::from_toml_str("name = \"t\"\n[scenario]\npath = \"s1\"\n", None)
            .expect("config");
        cfg.faults.controller_silence_ticks = silence;
        let q0 = DeltaRobot::default()
            .ik(&Vec3::new(0.0, 0.0, -0.4))
            .expect("reachable");
        PlantSide::from_config(&cfg, q0, 2).expect("plant")
    }

    #[test]
    fn states_count_up_and_the_tick_after_n_is_final() {
        let mut p = side(100);
        let hold = p.state();
        assert_eq!((hold.tick, hold.flags), (0, 0));
        for k in 0..3 {
            let reply = TorqueMsg {
                tick: k,
                tau: hold.tau_applied,
                ..TorqueMsg::default()
            };
            let tel = p.advance(Arrival::Reply(reply)).expect("advance");
            assert_eq!((tel.tick, tel.flags), (k, 0));
            let s = p.state();
            assert_eq!(s.tick, k + 1);
            assert_eq!(s.flags == wire::STATE_FINAL, k + 1 == 3, "tick {}", s.tick);
        }
        // An early end releases the controller with the true state, under any tick number.
        let f = p.final_state(9);
        assert_eq!((f.tick, f.flags), (9, wire::STATE_FINAL));
        assert_eq!((f.q, f.qd), (f.q_true, f.qd_true));
        assert_eq!(f.q, <[f64; 3]>::from(p.plant().sample().q));
    }

    #[test]
    fn a_miss_holds_and_the_silence_window_stops_the_loop() {
        let mut p = side(2);
        let s0 = p.state();
        let tel = p.advance(Arrival::Missed).expect("first miss is held");
        assert_eq!(tel.flags, wire::TEL_MISSED | wire::TEL_HELD);
        assert_eq!(tel.misses, 1);
        assert_eq!(p.state().tau_applied, s0.tau_applied, "held τᵃ_0");
        match p.advance(Arrival::Missed) {
            Err(PlantStop::ControllerSilent { tick: 1, cause }) => {
                assert!(cause.contains("2 consecutive ticks"), "{cause}")
            }
            other => panic!("expected a silence stop at tick 1, got {other:?}"),
        }
    }

    /// Regression: when the model failed integrating a tick, its telemetry was lost with it, so
    /// the trace's last row had an applied reply and no arrival, and `deltaloop replay` refused
    /// every run that diverged that way. The failed interval's telemetry (the reply's arrival)
    /// comes with the stop.
    #[test]
    fn regression_a_failed_interval_keeps_its_reply_arrival() {
        let mut cfg = RunConfig::from_toml_str(
            "name = \"t\"\n[scenario]\npath = \"s1\"\n[plant]\ntau_max_nm = 10000.0\n",
            None,
        )
        .expect("config");
        cfg.faults.controller_silence_ticks = 100;
        let q0 = DeltaRobot::default()
            .ik(&Vec3::new(0.0, 0.0, -0.4))
            .expect("reachable");
        let mut p = PlantSide::from_config(&cfg, q0, 1_000_000).expect("plant");
        let stop = (0..100_000u64)
            .find_map(|k| {
                let reply = TorqueMsg {
                    tick: k,
                    tau: [1e4, -1e4, 1e4],
                    ..TorqueMsg::default()
                };
                p.advance(Arrival::ReplyAfter(reply, 1_234)).err()
            })
            .expect("flung past the margins");
        let tel = stop.failed_interval().expect("a model failure");
        assert!(matches!(stop, PlantStop::Diverged { .. }), "{stop:?}");
        assert_eq!(tel.tick + 1, stop.tick());
        assert_eq!(tel.arrival_ns, 1_234);
        assert_eq!(tel.flags & wire::TEL_MISSED, 0);
    }
}
