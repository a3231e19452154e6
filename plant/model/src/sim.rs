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
    #[inline(always)]
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
        self.begin_interval();
        let h = self.cfg.ts / f64::from(self.cfg.substeps);
        for _ in 0..self.cfg.substeps {
            self.rk4(tau, h)?;
        }
        self.end_interval()
    }

    /// Starts control interval k (the payload step takes effect at its tick). For an interval cut
    /// into pieces: `begin_interval`, then [`PlantSim::piece`] for each, then
    /// [`PlantSim::end_interval`].
    pub fn begin_interval(&mut self) {
        if let Some(p) = self.cfg.payload_step
            && self.k == p.tick
        {
            self.robot.set_payload(p.mass_kg);
        }
    }

    /// Integrates a piece of `len_ns` (ns) of the current interval under τ (N m): ⌈len/h⌉ equal
    /// RK4 steps, h = Ts/substeps.
    pub fn piece(&mut self, len_ns: u64, tau: &Vec3) -> Result<(), KinematicsError> {
        let ts_ns = (self.cfg.ts * 1e9).round() as u128;
        let n = (u128::from(len_ns) * u128::from(self.cfg.substeps)).div_ceil(ts_ns.max(1));
        let n = u32::try_from(n.max(1)).unwrap_or(u32::MAX);
        let h = len_ns as f64 * 1e-9 / f64::from(n);
        for _ in 0..n {
            self.rk4(tau, h)?;
        }
        Ok(())
    }

    /// Ends the interval: checks the state is finite and advances k by one.
    pub fn end_interval(&mut self) -> Result<(), KinematicsError> {
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

/// What happened to commands in one interval, as the drives apply them.
#[derive(Clone, Copy, Debug, Default)]
struct IntervalFlags {
    /// Some command took effect in the interval.
    took_effect: bool,
    clamped: bool,
    rejected: bool,
}

/// The drives: clamp (or reject) commands beyond ±τ_max, reject non-finite ones, and apply each
/// command at its arrival instant (docs/delta-robot.md §5, "When a command takes effect").
///
/// All times are integer ns from t_0, Ts in ns. Command τ_j arrives at A_j = t_j + D + a_j (D the
/// fixed transport delay, a_j a measured latency, 0 outside realtime) and takes effect at
/// E_j = max(A_j, E_{j−1}): in tick order. It stays in effect until the next one takes effect.
/// Before the first command the holding torque τᵃ_0 acts, unclamped. A missing or rejected
/// command leaves the torque in effect (held). Interval k is cut at every instant a command takes
/// effect inside it; [`Plant::advance_after`] integrates the pieces. Capacity for the commands in
/// flight is reserved at construction.
#[derive(Clone, Debug)]
pub struct Actuator {
    tau_max: f64,
    /// Reject (hold) commands beyond ±τ_max instead of clamping them.
    reject_over_limit: bool,
    ts_ns: u64,
    delay_ns: u64,
    /// Commands not yet in effect: (E_j in ns from t_0, τ_j as commanded in N m).
    pending: std::collections::VecDeque<(u64, Vec3)>,
    last_due: u64,
    /// The torque in effect (N m), and whether it was clamped.
    current: Vec3,
    current_clamped: bool,
    /// τᵃ over the last interval (its time-average), N m.
    last: Vec3,
}

impl Actuator {
    /// `tau_max` in N m per joint, a fixed transport delay of `delay_ns` ns at a period of `ts_ns`
    /// ns, `tau_a0` (N m) the holding torque applied before the first command takes effect.
    pub fn new(tau_max: f64, delay_ns: u64, ts_ns: u64, tau_a0: Vec3) -> Self {
        let in_flight = (delay_ns / ts_ns.max(1)) as usize + 4;
        Self {
            tau_max,
            reject_over_limit: false,
            ts_ns: ts_ns.max(1),
            delay_ns,
            pending: std::collections::VecDeque::with_capacity(in_flight),
            last_due: 0,
            current: tau_a0,
            current_clamped: false,
            last: tau_a0,
        }
    }

    /// Rejects commands beyond ±τ_max (holding the last torque) instead of clamping them.
    pub fn reject_over_limit(mut self, yes: bool) -> Self {
        self.reject_over_limit = yes;
        self
    }

    /// The torque applied over the last interval (its time-average), N m.
    pub fn last_applied(&self) -> Vec3 {
        self.last
    }

    /// Applies a torque directly, bypassing the transport (a drive-local action such as a brake),
    /// clamped to ±τ_max. Returns what was applied.
    pub fn apply_local(&mut self, tau: Vec3) -> Vec3 {
        self.last = tau.map(|x| {
            if x.is_finite() {
                x.clamp(-self.tau_max, self.tau_max)
            } else {
                0.0
            }
        });
        self.current = self.last;
        self.last
    }

    /// Tick `tick`'s command reaches the drives `latency_ns` after t_tick + D.
    fn submit(&mut self, tick: u64, cmd: Vec3, latency_ns: u64) {
        // Saturating: an absurd latency puts the command past any run's end, never back near t_0.
        let arrival = tick
            .saturating_mul(self.ts_ns)
            .saturating_add(self.delay_ns)
            .saturating_add(latency_ns);
        let due = arrival.max(self.last_due);
        self.last_due = due;
        self.pending.push_back((due, cmd));
    }

    /// The next instant a command takes effect, if one is pending.
    fn next_due(&self) -> Option<u64> {
        self.pending.front().map(|&(due, _)| due)
    }

    /// Puts every command due at or before `at_ns` into effect, in order.
    fn take_due(&mut self, at_ns: u64, flags: &mut IntervalFlags) {
        while let Some(&(due, t)) = self.pending.front() {
            if due > at_ns {
                break;
            }
            self.pending.pop_front();
            if !t.iter().all(|x| x.is_finite())
                || (self.reject_over_limit && t.amax() > self.tau_max)
            {
                flags.rejected = true;
                continue;
            }
            let c = t.map(|x| x.clamp(-self.tau_max, self.tau_max));
            self.current = c;
            self.current_clamped = c != t;
            flags.clamped |= self.current_clamped;
            flags.took_effect = true;
        }
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
    /// `tau_max` (N m) and apply each command `transport_delay_ns` (ns) after its tick.
    pub fn new(
        robot: DeltaRobot,
        cfg: SimConfig,
        tau_max: f64,
        transport_delay_ns: u64,
        q0: Vec3,
    ) -> Result<Self, KinematicsError> {
        let pose = robot.pose(&q0)?;
        let tau_a0 = robot.gravity(&pose);
        let ts_ns = (cfg.ts * 1e9).round() as u64;
        let sim = PlantSim::new(robot, cfg, q0)?;
        Ok(Self {
            sim,
            drives: Actuator::new(tau_max, transport_delay_ns, ts_ns, tau_a0),
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

    /// Takes tick k's command (None: it did not arrive) and integrates [t_k, t_{k+1}), each
    /// command taking effect at its arrival (the transport delay after its tick).
    pub fn advance(&mut self, cmd: Option<Vec3>) -> Result<Applied, KinematicsError> {
        self.advance_after(cmd, 0)
    }

    /// [`Plant::advance`] for a command that reached the drives `latency_ns` (ns) after its tick
    /// plus the transport delay. An interval no command cuts is integrated exactly as with a
    /// constant torque (substeps RK4 steps of h); one cut at instants inside it is integrated
    /// piece by piece (⌈λ/h⌉ equal steps for a piece of λ), and its τᵃ is the time-average of the
    /// torque over it.
    pub fn advance_after(
        &mut self,
        cmd: Option<Vec3>,
        latency_ns: u64,
    ) -> Result<Applied, KinematicsError> {
        let k = self.sim.tick();
        let d = &mut self.drives;
        if let Some(c) = cmd {
            d.submit(k, c, latency_ns);
        }
        let t0 = k * d.ts_ns;
        let t1 = t0 + d.ts_ns;
        let mut flags = IntervalFlags::default();
        d.take_due(t0, &mut flags);
        let tau_a = if d.next_due().is_some_and(|due| due < t1) {
            // Cut: the torque carried into the interval counts for the clamp flag too.
            flags.clamped |= d.current_clamped;
            self.sim.begin_interval();
            let (mut at, mut sum) = (t0, Vec3::zeros());
            while let Some(due) = d.next_due().filter(|&due| due < t1) {
                self.sim.piece(due - at, &d.current)?;
                sum += d.current * (due - at) as f64;
                at = due;
                d.take_due(due, &mut flags);
            }
            self.sim.piece(t1 - at, &d.current)?;
            sum += d.current * (t1 - at) as f64;
            self.sim.end_interval()?;
            sum / d.ts_ns as f64
        } else {
            self.sim.step(&d.current)?;
            d.current
        };
        d.last = tau_a;
        // Before the first command can arrive the holding torque is the plan, not a hold.
        let initial = t1 <= d.delay_ns;
        Ok(Applied {
            tau: tau_a,
            clamped: flags.clamped,
            held: !flags.took_effect && !initial,
            rejected: flags.rejected,
        })
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

#[cfg(test)]
mod tests {
    use super::*;

    fn plant(delay_ns: u64) -> Plant {
        let robot = DeltaRobot::default();
        let q0 = robot.ik(&Vec3::new(0.0, 0.0, -0.43)).unwrap();
        Plant::new(robot, SimConfig::default(), 100.0, delay_ns, q0).unwrap()
    }

    /// D = 45 µs, hand-checked: interval k applies τ_{k−1} over [t_k, t_k + 45 µs) and τ_k over
    /// the rest; τᵃ is the time-average (45 000·τ_old + 255 000·τ_new)/300 000; a clamped command
    /// marks both intervals it acts in; a missing command leaves an uncut, held interval.
    #[test]
    fn a_sub_tick_delay_cuts_the_interval_averages_tau_and_flags_the_clamp() {
        let mut p = plant(45_000);
        let g = p.sample().tau_applied;
        let avg = |old: Vec3, new: Vec3| (old * 45_000.0 + new * 255_000.0) / 300_000.0;
        let c0 = Vec3::new(1.0, -2.0, 3.0);
        let a = p.advance(Some(c0)).unwrap();
        assert_eq!(a.tau, avg(g, c0));
        assert!(!a.clamped && !a.held && !a.rejected);
        // Over the limit: clamped to ±100 N m.
        let a = p.advance(Some(Vec3::new(500.0, 0.0, 0.0))).unwrap();
        let c1 = Vec3::new(100.0, 0.0, 0.0);
        assert_eq!(a.tau, avg(c0, c1));
        assert!(a.clamped && !a.held);
        // The clamped command still acts over the first 45 µs of the next interval.
        let c2 = Vec3::new(0.5, 0.5, 0.5);
        let a = p.advance(Some(c2)).unwrap();
        assert_eq!(a.tau, avg(c1, c2));
        assert!(a.clamped);
        // No command for tick 3: τ_2 goes on over the whole interval (no cut), held.
        let a = p.advance(None).unwrap();
        assert_eq!(a.tau, c2);
        assert!(a.held && !a.clamped);
        assert_eq!(p.sample().tau_applied, c2);
    }

    /// The same commands with D = 300 µs and with no delay: whole ticks cut nothing, so the
    /// delayed plant is the undelayed one shifted by one tick, bit for bit, after the holding
    /// torque's first interval.
    #[test]
    fn a_whole_tick_delay_cuts_nothing() {
        let cmds: Vec<Vec3> = (0..20)
            .map(|k| Vec3::new(0.1 * k as f64, -0.05 * k as f64, 0.02))
            .collect();
        let mut late = plant(300_000);
        let a = late.advance(Some(cmds[0])).unwrap();
        assert_eq!(a.tau, late.sample().tau_applied);
        assert!(!a.held && !a.clamped);
        let mut seen = Vec::new();
        for c in &cmds[1..] {
            seen.push(late.advance(Some(*c)).unwrap().tau);
        }
        assert_eq!(seen, cmds[..19].to_vec());
    }

    /// A command that would arrive before its predecessor waits for it (tick order).
    #[test]
    fn commands_take_effect_in_tick_order() {
        let mut p = plant(0);
        let (c0, c1) = (Vec3::repeat(1.0), Vec3::repeat(2.0));
        // τ_0 arrives 250 µs after t_0; τ_1 would arrive at t_1 + 0, after it: no reordering.
        let a = p.advance_after(Some(c0), 250_000).unwrap();
        let g = Plant::new(
            DeltaRobot::default(),
            SimConfig::default(),
            100.0,
            0,
            DeltaRobot::default()
                .ik(&Vec3::new(0.0, 0.0, -0.43))
                .unwrap(),
        )
        .unwrap()
        .sample()
        .tau_applied;
        assert_eq!(a.tau, (g * 250_000.0 + c0 * 50_000.0) / 300_000.0);
        let a = p.advance_after(Some(c1), 0).unwrap();
        assert_eq!(a.tau, c1);
        // τ_2 sent with a 350 µs latency lands in interval 3: interval 2 holds τ_1.
        let a = p.advance_after(Some(Vec3::repeat(3.0)), 350_000).unwrap();
        assert_eq!(a.tau, c1);
        assert!(a.held);
        // τ_3 arrives at t_3, before τ_2 (t_3 + 50 µs): it waits, and takes effect right after
        // it, at the same instant; τ_2 acts for no time at all.
        let c3 = Vec3::repeat(4.0);
        let a = p.advance_after(Some(c3), 0).unwrap();
        assert_eq!(a.tau, (c1 * 50_000.0 + c3 * 250_000.0) / 300_000.0);
        assert!(!a.held);
    }

    /// Regression: a latency of `u64::MAX` (read from a tampered trace) overflowed the arrival
    /// time: it wrapped to before t_0 in a release build and panicked in a debug one. It now
    /// arrives after any run's end: the drives hold, and the commands after it wait behind it.
    #[test]
    fn regression_huge_latency_never_wraps_around() {
        let mut p = plant(45_000);
        let a = p.advance_after(Some(Vec3::repeat(1.0)), u64::MAX).unwrap();
        assert!(a.held);
        let a = p.advance_after(Some(Vec3::repeat(2.0)), 0).unwrap();
        assert!(a.held);
    }
}
