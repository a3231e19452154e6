//! Plant simulation (docs/delta-robot.md §5): classical RK4 with a fixed step h = Ts/substeps, the torque held
//! constant over each control interval [kTs, (k+1)Ts) (zero-order hold), friction evaluated at every
//! stage, and the drives ([`Actuator`]): clamp, transport delay and hold-on-miss.

use crate::{DeltaRobot, KinematicsError, Vec3};

/// A payload step (docs/delta-robot.md §4.3): m_pay jumps to `mass_kg` at the start of control tick `tick`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PayloadStep {
    /// Payload mass after the step, kg.
    pub mass_kg: f64,
    /// First control tick (k, t = k·Ts) that sees the new mass.
    pub tick: u64,
}

/// How the plant integrates.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SimConfig {
    /// Control period Ts, s.
    pub ts: f64,
    /// RK4 steps per control period (h = Ts/substeps).
    pub substeps: u32,
    /// Joint friction d_f = Fv q̇ + Fc tanh(q̇/ε) on or off.
    pub friction: bool,
    /// Fail when a step starts past the singularity margins (docs/delta-robot.md §3.5).
    pub check_margins: bool,
    /// Optional payload step.
    pub payload_step: Option<PayloadStep>,
}

impl Default for SimConfig {
    /// Ts = 0.3 ms, 10 substeps (h = 30 µs), no friction, margins checked, no payload step.
    fn default() -> Self {
        Self {
            ts: 3e-4,
            substeps: 10,
            friction: false,
            check_margins: true,
            payload_step: None,
        }
    }
}

/// The robot state integrated in time: joint angles q (rad) and rates q̇ (rad/s) at tick k.
#[derive(Clone, Debug)]
pub struct PlantSim {
    robot: DeltaRobot,
    cfg: SimConfig,
    q: Vec3,
    qd: Vec3,
    k: u64,
}

impl PlantSim {
    /// Starts at rest (q̇ = 0) at joint angles `q0` (rad), tick 0. Fails if q0 cannot be assembled
    /// or is past the singularity margins.
    pub fn new(robot: DeltaRobot, cfg: SimConfig, q0: Vec3) -> Result<Self, KinematicsError> {
        let pose = robot.pose(&q0)?;
        if cfg.check_margins {
            robot.check_margins(&pose)?;
        }
        Ok(Self {
            robot,
            cfg,
            q: q0,
            qd: Vec3::zeros(),
            k: 0,
        })
    }

    /// Joint angles q, rad.
    pub fn q(&self) -> Vec3 {
        self.q
    }

    /// Joint rates q̇, rad/s.
    pub fn qd(&self) -> Vec3 {
        self.qd
    }

    /// Current control tick k (the state is at t = k·Ts).
    pub fn tick(&self) -> u64 {
        self.k
    }

    /// The model, with the payload currently in effect.
    pub fn robot(&self) -> &DeltaRobot {
        &self.robot
    }

    /// The integration settings.
    pub fn config(&self) -> &SimConfig {
        &self.cfg
    }

    /// Overwrites the state (for tests and energy checks): q in rad, q̇ in rad/s.
    pub fn set_state(&mut self, q: Vec3, qd: Vec3) {
        self.q = q;
        self.qd = qd;
    }

    /// (q̇, q̈) at (q, q̇) under joint torque τ (N m), including friction if enabled.
    #[inline]
    fn deriv(&self, q: &Vec3, qd: &Vec3, tau: &Vec3, check: bool) -> Result<Vec3, KinematicsError> {
        let pose = self.robot.pose(q)?;
        if check {
            self.robot.check_margins(&pose)?;
        }
        let tau_net = if self.cfg.friction {
            tau - self.robot.friction(qd)
        } else {
            *tau
        };
        self.robot.forward_dynamics(&pose, qd, &tau_net)
    }

    /// Integrates one control period with τ (N m) held constant, advancing k by one.
    /// On error the state is left at the start of the failing substep.
    pub fn step(&mut self, tau: &Vec3) -> Result<(), KinematicsError> {
        if let Some(p) = self.cfg.payload_step
            && self.k == p.tick
        {
            self.robot.set_payload(p.mass_kg);
        }
        let h = self.cfg.ts / f64::from(self.cfg.substeps);
        for _ in 0..self.cfg.substeps {
            self.rk4(tau, h)?;
        }
        // Never hand out a NaN state: a diverged simulation is a fault that names where.
        if !(self.q.iter().chain(self.qd.iter()).all(|x| x.is_finite())) {
            return Err(KinematicsError::NonFinite {
                q: [self.q[0], self.q[1], self.q[2]],
            });
        }
        self.k += 1;
        Ok(())
    }

    /// One classical RK4 step of size h (s).
    pub fn rk4(&mut self, tau: &Vec3, h: f64) -> Result<(), KinematicsError> {
        let (q, v) = (self.q, self.qd);
        let a1 = self.deriv(&q, &v, tau, self.cfg.check_margins)?;
        let (q2, v2) = (q + v * (h / 2.0), v + a1 * (h / 2.0));
        let a2 = self.deriv(&q2, &v2, tau, false)?;
        let (q3, v3) = (q + v2 * (h / 2.0), v + a2 * (h / 2.0));
        let a3 = self.deriv(&q3, &v3, tau, false)?;
        let (q4, v4) = (q + v3 * h, v + a3 * h);
        let a4 = self.deriv(&q4, &v4, tau, false)?;
        self.q = q + (v + v2 * 2.0 + v3 * 2.0 + v4) * (h / 6.0);
        self.qd = v + (a1 + a2 * 2.0 + a3 * 2.0 + a4) * (h / 6.0);
        Ok(())
    }
}

/// What the drives applied over one interval.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Applied {
    /// Torque applied over [t_k, t_{k+1}) (= τᵃ_{k+1}), N m.
    pub tau: Vec3,
    /// Some joint was clamped to ±τ_max.
    pub clamped: bool,
    /// The command due this interval was missing or rejected, so the last torque was held.
    pub held: bool,
    /// The command was rejected (non-finite, or beyond ±τ_max under the `reject` policy).
    pub rejected: bool,
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum Slot {
    /// Before the first command arrives through the delay line: the holding torque τᵃ_0.
    Initial,
    Command(Vec3),
    Missed,
}

/// The drives: clamp (or reject) commands beyond ±τ_max, reject non-finite ones, delay commands by
/// d ticks, and hold the last applied torque when a command is missing or rejected. Fixed
/// capacity: allocates only at construction.
#[derive(Clone, Debug)]
pub struct Actuator {
    tau_max: f64,
    /// Reject (hold) commands beyond ±τ_max instead of clamping them.
    reject_over_limit: bool,
    line: Vec<Slot>,
    head: usize,
    last: Vec3,
    initial: Vec3,
}

impl Actuator {
    /// `tau_max` in N m per joint, `delay` in ticks, `tau_a0` (N m) the holding torque applied
    /// before the start (reported as τᵃ_0 and applied, unclamped, while the delay line fills).
    pub fn new(tau_max: f64, delay: usize, tau_a0: Vec3) -> Self {
        Self {
            tau_max,
            reject_over_limit: false,
            line: vec![Slot::Initial; delay],
            head: 0,
            last: tau_a0,
            initial: tau_a0,
        }
    }

    /// Rejects commands beyond ±τ_max (holding the last torque) instead of clamping them.
    pub fn reject_over_limit(mut self, yes: bool) -> Self {
        self.reject_over_limit = yes;
        self
    }

    /// The torque applied over the last interval, N m.
    pub fn last_applied(&self) -> Vec3 {
        self.last
    }

    /// Applies a torque directly, bypassing the delay line (a drive-local action such as a brake),
    /// clamped to ±τ_max. Returns what was applied.
    pub fn apply_local(&mut self, tau: Vec3) -> Vec3 {
        self.last = tau.map(|x| {
            if x.is_finite() {
                x.clamp(-self.tau_max, self.tau_max)
            } else {
                0.0
            }
        });
        self.last
    }

    /// Takes tick k's command (None when it did not arrive in time) and returns the torque
    /// applied over [t_k, t_{k+1}), which is the command of tick k − d.
    pub fn apply(&mut self, cmd: Option<Vec3>) -> Applied {
        let incoming = match cmd {
            Some(t) => Slot::Command(t),
            None => Slot::Missed,
        };
        let due = if self.line.is_empty() {
            incoming
        } else {
            let out = std::mem::replace(&mut self.line[self.head], incoming);
            self.head = (self.head + 1) % self.line.len();
            out
        };
        let hold = |rejected| Applied {
            tau: self.last,
            clamped: false,
            held: true,
            rejected,
        };
        let applied = match due {
            Slot::Initial => Applied {
                tau: self.initial,
                clamped: false,
                held: false,
                rejected: false,
            },
            Slot::Missed => hold(false),
            Slot::Command(t) if !t.iter().all(|x| x.is_finite()) => hold(true),
            Slot::Command(t) if self.reject_over_limit && t.amax() > self.tau_max => hold(true),
            Slot::Command(t) => {
                let c = t.map(|x| x.clamp(-self.tau_max, self.tau_max));
                Applied {
                    tau: c,
                    clamped: c != t,
                    held: false,
                    rejected: false,
                }
            }
        };
        self.last = applied.tau;
        applied
    }
}

/// The plant's state at tick k as the drives and encoders report it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PlantSample {
    /// Control tick k (t = k·Ts).
    pub k: u64,
    /// Joint angles q_k, rad.
    pub q: Vec3,
    /// Joint rates q̇_k, rad/s.
    pub qd: Vec3,
    /// Torque applied over [t_{k−1}, t_k) (τᵃ_k), N m; at k = 0 the holding torque G(q_0).
    pub tau_applied: Vec3,
}

/// The whole plant: robot dynamics, drives and sensors. Every loop mode steps this one type.
#[derive(Clone, Debug)]
pub struct Plant {
    sim: PlantSim,
    drives: Actuator,
    sensor: Option<crate::sensor::Sensor>,
}

impl Plant {
    /// The robot at rest at `q0` (rad), holding itself with τᵃ_0 = G(q_0) (N m); drives clamp at
    /// `tau_max` (N m) and apply commands `transport_delay` ticks late.
    pub fn new(
        robot: DeltaRobot,
        cfg: SimConfig,
        tau_max: f64,
        transport_delay: usize,
        q0: Vec3,
    ) -> Result<Self, KinematicsError> {
        let pose = robot.pose(&q0)?;
        let tau_a0 = robot.gravity(&pose);
        let sim = PlantSim::new(robot, cfg, q0)?;
        Ok(Self {
            sim,
            drives: Actuator::new(tau_max, transport_delay, tau_a0),
            sensor: None,
        })
    }

    /// Adds a sensor model: [`Plant::measure`] then perturbs q and q̇ (truth stays in [`Plant::sample`]).
    pub fn with_sensor(mut self, s: crate::sensor::Sensor) -> Self {
        self.sensor = Some(s);
        self
    }

    /// The current sample (tick k, q, q̇, τᵃ_k).
    pub fn sample(&self) -> PlantSample {
        PlantSample {
            k: self.sim.tick(),
            q: self.sim.q(),
            qd: self.sim.qd(),
            tau_applied: self.drives.last_applied(),
        }
    }

    /// What the encoders report at this tick: [`Plant::sample`] with q and q̇ through the sensor
    /// model (identical to it without one). Call once per tick: it advances the noise stream.
    pub fn measure(&mut self) -> PlantSample {
        let mut s = self.sample();
        if let Some(sensor) = self.sensor.as_mut() {
            (s.q, s.qd) = sensor.measure(&s.q, &s.qd);
        }
        s
    }

    /// Applies tick k's command (None: it did not arrive) over [t_k, t_{k+1}) and integrates.
    pub fn advance(&mut self, cmd: Option<Vec3>) -> Result<Applied, KinematicsError> {
        let applied = self.drives.apply(cmd);
        self.sim.step(&applied.tau)?;
        Ok(applied)
    }

    /// The drives' brake for a safe stop: τ = G(q) − D q̇ (hold against gravity, damp the motion),
    /// D in N m s/rad.
    pub fn brake_torque(&self, damping: f64) -> Result<Vec3, KinematicsError> {
        let pose = self.sim.robot().pose(&self.sim.q())?;
        Ok(self.sim.robot().gravity(&pose) - self.sim.qd() * damping)
    }

    /// One tick of safe stop: the drives apply the brake directly (no controller, no delay line).
    pub fn brake_tick(&mut self, damping: f64) -> Result<Vec3, KinematicsError> {
        let tau = self.drives.apply_local(self.brake_torque(damping)?);
        self.sim.step(&tau)?;
        Ok(tau)
    }

    /// Rejects commands beyond ±τ_max instead of clamping them.
    pub fn reject_over_limit(mut self, yes: bool) -> Self {
        self.drives = self.drives.reject_over_limit(yes);
        self
    }

    /// The simulation (model and integrator state).
    pub fn sim(&self) -> &PlantSim {
        &self.sim
    }
}
