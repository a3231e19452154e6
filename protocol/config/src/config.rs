//! The scenario configuration (TOML): schema, presets, and validation.
//!
//! A file names a scenario, the plant options, the controller laws and a preset of controller
//! constants (`matched` or `paper`, see the docs/controllers.md), and may override any constant key by
//! key. [`RunConfig::from_toml_str`] rejects unknown keys and out-of-range values with an error that
//! names the key, the value and what is allowed. The resolved config ([`RunConfig::to_toml_string`])
//! has every constant filled in and parses back to the same config.

pub use deltaloop_law::{ControllerParams, Law, Preset, VelocitySource};
use serde::{Deserialize, Serialize};
use std::fmt;
use std::path::Path;

/// A config problem, naming the key, the value and what is allowed. Every message is one line:
/// echoed text has its control and format characters escaped and is cut to
/// [`MAX_ECHO_CHARS`] characters.
#[derive(Debug, thiserror::Error, Clone, PartialEq)]
pub enum ConfigError {
    /// The file could not be read (missing, not a regular file, too large, not UTF-8).
    #[error("cannot read config file {path}: {reason}")]
    Read { path: String, reason: String },
    /// The text is not valid TOML for this schema (unknown key, wrong type, syntax), and where
    /// (1-based line and column, in characters), if the parser said.
    #[error(
        "invalid config{}: {message}{}",
        path.as_deref().map(|p| format!(" {p}")).unwrap_or_default(),
        position.map(|(l, c)| format!(" at line {l}, column {c}")).unwrap_or_default()
    )]
    Parse {
        path: Option<String>,
        message: String,
        position: Option<(usize, usize)>,
    },
    /// A key has a value outside its allowed range.
    #[error("config key `{key}` = {value} is out of range: {allowed}")]
    Range {
        key: String,
        value: String,
        allowed: String,
    },
}

deltaloop_law::text_enum! {
    "kebab-case", "path";
    /// Which reference path to follow (docs/delta-robot.md §6).
    pub enum PathKind {
        /// P0 → P2 semi-ellipse, T = 0.8 s.
        S1,
        /// The same path in T = 0.2 s.
        S2,
        /// P0 → P1 → P2, two semi-ellipses in different vertical planes, T = 1.2 s.
        S3,
        /// The `segments` list of the scenario table.
        Custom,
    }
}

impl PathKind {
    /// Motion duration T of the paper scenarios, s (None for `custom`: the segments say).
    pub fn paper_duration_s(self) -> Option<f64> {
        match self {
            PathKind::S1 => Some(0.8),
            PathKind::S2 => Some(0.2),
            PathKind::S3 => Some(1.2),
            PathKind::Custom => None,
        }
    }
}

/// One semi-elliptic segment (docs/delta-robot.md §6), traversed with a rest-to-rest quintic time law.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Segment {
    /// Start point, m, base frame.
    pub from: [f64; 3],
    /// End point, m, base frame.
    pub to: [f64; 3],
    /// Apex height h above the chord, m.
    pub apex_m: f64,
    /// Segment duration, s.
    pub duration_s: f64,
}

/// `[scenario]`: the reference motion.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ScenarioSection {
    /// `s1`, `s2`, `s3` or `custom`.
    pub path: PathKind,
    /// Segments, only with `path = "custom"`.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub segments: Vec<Segment>,
    /// Extra time after the motion ends, s (the reference holds its end point). Metrics cover the
    /// whole run.
    #[serde(default)]
    pub hold_s: f64,
}

/// `[plant]`: the simulated robot.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PlantSection {
    /// Joint friction d_f = Fv q̇ + Fc tanh(q̇/ε) on (true) or off.
    #[serde(default)]
    pub friction: bool,
    /// Drive torque limit per joint, N m.
    #[serde(default = "default_tau_max")]
    pub tau_max_nm: f64,
    /// RK4 steps per control period (h = Ts/substeps).
    #[serde(default = "default_substeps")]
    pub substeps: u32,
    /// Transport delay in whole ticks d: with `transport_delay_us` = 0 the plant applies τ_k over
    /// [t_{k+d}, t_{k+d+1}). The delay D is d·Ts + `transport_delay_us`.
    #[serde(default)]
    pub transport_delay_samples: u32,
    /// Transport delay beyond the whole ticks, µs (any value ≥ 0; converted to integer ns): τ_k
    /// takes effect at t_k + D, cutting the interval it falls in (docs/delta-robot.md §5).
    #[serde(default)]
    pub transport_delay_us: f64,
    /// Run this executable (program, then arguments) in place of the built-in `deltaloop-plant`;
    /// it gets the same arguments after these (`--run-id`, `--config`, `--mode`) and must speak
    /// the wire contract (docs/protocol.md). Empty: the built-in plant.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub command: Vec<String>,
    /// In realtime mode, when a reply takes effect: at its measured arrival (`arrival`: its
    /// publish time minus the tick's deadline, plus D) or at its tick (`tick`: as if the reply
    /// had been instantaneous; plus D). Other modes have no measured arrival.
    #[serde(default)]
    pub apply_torque: ApplyTorque,
    /// Payload step (docs/delta-robot.md §4.3): m_pay jumps from 0 to this mass, kg (0: no step).
    #[serde(default)]
    pub payload_step_kg: f64,
    /// When the payload step happens, s; the first control instant at or after it. Default: T/2.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub payload_step_at_s: Option<f64>,
}

fn default_tau_max() -> f64 {
    100.0
}
fn default_substeps() -> u32 {
    10
}

impl Default for PlantSection {
    fn default() -> Self {
        Self {
            friction: false,
            tau_max_nm: default_tau_max(),
            substeps: default_substeps(),
            transport_delay_samples: 0,
            transport_delay_us: 0.0,
            apply_torque: ApplyTorque::default(),
            command: Vec::new(),
            payload_step_kg: 0.0,
            payload_step_at_s: None,
        }
    }
}

/// When a realtime reply takes effect (`[plant] apply_torque`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "kebab-case")]
pub enum ApplyTorque {
    /// At its measured arrival (plus the configured transport delay).
    #[default]
    Arrival,
    /// At its tick (plus the configured transport delay), whatever the reply really took.
    Tick,
}

/// What the drives do with a command beyond ±τ_max (non-finite commands are always rejected).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "kebab-case")]
pub enum TorqueLimit {
    /// Clamp each joint to ±τ_max (counted).
    #[default]
    Clamp,
    /// Reject the whole command and hold the last applied torque (counted).
    Reject,
}

/// A controller fault to inject, for drills and tests: `none`, or `<kind>@<tick>` with kind
/// `nan-torque` (send NaN), `panic` (the process panics), `stall` (stop answering).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum FaultInjection {
    #[default]
    None,
    NanTorque(u64),
    Panic(u64),
    Stall(u64),
}

impl FaultInjection {
    fn parse(s: &str) -> Result<Self, String> {
        if s == "none" {
            return Ok(Self::None);
        }
        let bad =
            || format!("`{s}`: expected none, nan-torque@<tick>, panic@<tick> or stall@<tick>");
        let (kind, tick) = s.split_once('@').ok_or_else(bad)?;
        let tick: u64 = tick.parse().map_err(|_| bad())?;
        match kind {
            "nan-torque" => Ok(Self::NanTorque(tick)),
            "panic" => Ok(Self::Panic(tick)),
            "stall" => Ok(Self::Stall(tick)),
            _ => Err(bad()),
        }
    }
}

impl std::fmt::Display for FaultInjection {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::None => f.write_str("none"),
            Self::NanTorque(k) => write!(f, "nan-torque@{k}"),
            Self::Panic(k) => write!(f, "panic@{k}"),
            Self::Stall(k) => write!(f, "stall@{k}"),
        }
    }
}

impl Serialize for FaultInjection {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(&self.to_string())
    }
}

impl<'de> Deserialize<'de> for FaultInjection {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let s = String::deserialize(d)?;
        Self::parse(&s).map_err(serde::de::Error::custom)
    }
}

/// `[faults]`: how the loop reacts to a misbehaving peer, and fault injection.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FaultSection {
    /// Realtime: this many consecutive missing torques declare the controller dead. The plant holds
    /// the last applied torque through them (the hold window), then stops safely.
    #[serde(default = "default_silence_ticks")]
    pub controller_silence_ticks: u32,
    /// Safe stop after a fault: the drives brake with τ = G(q) − D q̇ for this long, then the plant exits, ms.
    #[serde(default = "default_safe_stop_ms")]
    pub safe_stop_ms: u32,
    /// Brake damping D of the safe stop, N m s/rad.
    #[serde(default = "default_brake")]
    pub brake_damping_nm_s: f64,
    /// Commands beyond ±τ_max: `clamp` or `reject`.
    #[serde(default)]
    pub torque_limit: TorqueLimit,
    /// Controller fault injection (see [`FaultInjection`]).
    #[serde(default)]
    pub inject: FaultInjection,
}

fn default_silence_ticks() -> u32 {
    100
}
fn default_safe_stop_ms() -> u32 {
    100
}
fn default_brake() -> f64 {
    2.0
}

impl Default for FaultSection {
    fn default() -> Self {
        Self {
            controller_silence_ticks: default_silence_ticks(),
            safe_stop_ms: default_safe_stop_ms(),
            brake_damping_nm_s: default_brake(),
            torque_limit: TorqueLimit::Clamp,
            inject: FaultInjection::None,
        }
    }
}

/// `[sensor]`: measurement realism, off by default. The plant adds seeded Gaussian noise, then
/// quantises q to encoder counts; ground truth stays noise-free for evaluation.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SensorSection {
    /// Encoder counts per revolution on the joint (0: no quantisation).
    #[serde(default)]
    pub encoder_counts_per_rev: u32,
    /// Standard deviation of the noise added to q, rad.
    #[serde(default)]
    pub q_noise_std_rad: f64,
    /// Standard deviation of the noise added to q̇, rad/s.
    #[serde(default)]
    pub qd_noise_std_rad_s: f64,
    /// Seed of the noise (same seed, same run).
    #[serde(default = "default_seed")]
    pub seed: u64,
    /// Controller velocity source.
    #[serde(default)]
    pub velocity: VelocitySource,
}

fn default_seed() -> u64 {
    1
}

impl Default for SensorSection {
    fn default() -> Self {
        Self {
            encoder_counts_per_rev: 0,
            q_noise_std_rad: 0.0,
            qd_noise_std_rad_s: 0.0,
            seed: default_seed(),
            velocity: VelocitySource::Measured,
        }
    }
}

impl SensorSection {
    /// Whether the plant perturbs measurements at all.
    pub fn is_ideal(&self) -> bool {
        self.encoder_counts_per_rev == 0
            && self.q_noise_std_rad == 0.0
            && self.qd_noise_std_rad_s == 0.0
    }
}

/// `[controller]`: laws, preset, TDE delay, and per-key overrides of the preset's constants.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ControllerSection {
    /// The preset the constants start from.
    #[serde(default)]
    pub preset: Preset,
    /// The laws to run (each is one run of the scenario).
    #[serde(default = "default_laws")]
    pub laws: Vec<Law>,
    /// TDE delay ℓ (L = ℓ·Ts), ticks, ≥ 1.
    #[serde(default = "default_ell")]
    pub tde_delay_samples: u32,
    /// Extra wall time the controller process spends before each reply, µs (realtime: real
    /// misses; lockstep: only slower; inproc: no effect).
    #[serde(default)]
    pub compute_delay_us: u32,
    /// Run this executable (program, then arguments) in place of the built-in
    /// `deltaloop-controller` in the process modes; it gets the same arguments after these
    /// (`--run-id`, `--config`, `--mode`, `--law`) and must speak the wire contract
    /// (docs/protocol.md). Empty: the built-in controller.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub command: Vec<String>,
    /// Overrides (None: the preset's value). See [`ControllerParams`] for units.
    pub m_bar: Option<f64>,
    pub kp: Option<f64>,
    pub kd: Option<f64>,
    pub ks: Option<f64>,
    pub phi: Option<f64>,
    pub k1: Option<f64>,
    pub k2: Option<f64>,
    pub pid_p: Option<f64>,
    pub pid_i: Option<f64>,
    pub pid_d: Option<f64>,
}

fn default_laws() -> Vec<Law> {
    Law::ALL.to_vec()
}
fn default_ell() -> u32 {
    1
}

impl Default for ControllerSection {
    fn default() -> Self {
        toml::from_str("").expect("empty controller section")
    }
}

/// Where and how the two loop processes run in one mode. Missing keys take the mode's default
/// (see [`Layout::realtime_default`], [`Layout::lockstep_default`]); the resolved config lists all.
#[derive(Clone, Debug, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Layout {
    /// CPU for the plant process (−1: not pinned).
    pub plant_cpu: Option<i32>,
    /// CPU for the controller process (−1: not pinned).
    pub controller_cpu: Option<i32>,
    /// CPU for the supervisor's collector (−1: not pinned).
    pub supervisor_cpu: Option<i32>,
    /// SCHED_FIFO priority of the plant, 1..=99 (0: SCHED_OTHER).
    pub plant_priority: Option<i32>,
    /// SCHED_FIFO priority of the controller, 1..=99 (0: SCHED_OTHER).
    pub controller_priority: Option<i32>,
    /// How long a process busy-polls for its peer's message before blocking, µs.
    pub spin_us: Option<u32>,
    /// mlockall in both loop processes.
    pub lock_memory: Option<bool>,
    /// Realtime: the plant sleeps until this long before each deadline and busy-waits the rest,
    /// absorbing the timer's wake-up latency, µs (0: sleep to the deadline). At most one control
    /// period (Ts in µs).
    pub wake_early_us: Option<u32>,
    /// Realtime: the controller knows the schedule (t0, Ts) from START; it sleeps until this
    /// long before each deadline, then polls for the state (up to `spin_us` past the deadline)
    /// before it blocks on the wake-up event, µs. −1: it blocks on the event right after each
    /// reply and is woken by the plant's notification. At most one period. Lockstep ignores it.
    pub controller_wake_early_us: Option<i32>,
    /// What a process does between two looks for its peer's message while it polls: `spin` on
    /// its CPU, or `yield` the CPU to a peer at the same SCHED_FIFO priority on the same CPU
    /// (plant and controller share one CPU without a wake-up notification).
    pub poll: Option<Poll>,
}

/// What a polling process does between two looks for its peer's message.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "kebab-case")]
pub enum Poll {
    /// Busy-wait (a spin-loop hint): for a peer on another CPU.
    #[default]
    Spin,
    /// `sched_yield`: the CPU goes to a peer of the same SCHED_FIFO priority waiting on it, and
    /// comes back when that peer yields or sleeps. Needs plant and controller on one CPU at one
    /// priority (checked): a process of lower priority would never get the CPU from a yield.
    Yield,
}

deltaloop_law::text_enum! {
    "kebab-case", "mode";
    /// How plant and controller are connected: one enum for the CLI, the sweep and the processes.
    #[derive(Default)]
    pub enum LoopMode {
        /// Plant and controller stepped together in one process. Fastest; for sweeps and tests.
        #[default]
        Inproc,
        /// Real processes over iceoryx2; the plant waits for every torque (bit-identical to inproc).
        Lockstep,
        /// Real processes over iceoryx2 on an absolute clock; late torques are missed.
        Realtime,
    }
}

impl LoopMode {
    /// Every mode, in documentation order.
    pub const ALL: &'static [LoopMode] = <LoopMode as strum::VariantArray>::VARIANTS;

    /// Parses the mode of a loop process: `lockstep` or `realtime` (a process is never inproc).
    pub fn parse_process(s: &str) -> Result<LoopMode, String> {
        match LoopMode::parse(s)? {
            LoopMode::Inproc => {
                let allowed: Vec<&str> = LoopMode::ALL
                    .iter()
                    .filter(|m| m.is_process())
                    .map(|m| m.name())
                    .collect();
                Err(format!(
                    "mode `{s}` has no processes (allowed: {})",
                    allowed.join(", ")
                ))
            }
            m => Ok(m),
        }
    }

    /// Whether plant and controller run as separate processes.
    pub fn is_process(self) -> bool {
        self != LoopMode::Inproc
    }

    /// The scheduling layout of this mode's processes (None for inproc).
    pub fn layout(self, cfg: &RunConfig) -> Option<&Layout> {
        match self {
            LoopMode::Inproc => None,
            LoopMode::Lockstep => Some(&cfg.loop_.lockstep),
            LoopMode::Realtime => Some(&cfg.loop_.realtime),
        }
    }
}

impl Layout {
    /// Realtime default, the fewest misses measured on a 2-vCPU VM: plant and controller share
    /// CPU 1 under SCHED_FIFO (plant above controller); the plant wakes 80 µs early and blocks on
    /// the reply's wake-up, the controller sleeps until 50 µs before each deadline and polls for
    /// the state, so it is already running when the plant hands over the CPU. The supervisor on
    /// CPU 0. A freeze of one virtual CPU by the host stalls plant and controller together: late
    /// wakes, not misses.
    pub fn realtime_default() -> Self {
        Self {
            plant_cpu: Some(1),
            controller_cpu: Some(1),
            supervisor_cpu: Some(0),
            plant_priority: Some(80),
            controller_priority: Some(70),
            spin_us: Some(0),
            lock_memory: Some(true),
            wake_early_us: Some(80),
            controller_wake_early_us: Some(50),
            poll: Some(Poll::Spin),
        }
    }

    /// The shortest round trip: plant on CPU 1, controller on CPU 0, both SCHED_FIFO; the plant
    /// polls for the reply through the budget, both sleep until 200 µs before each deadline and
    /// poll from there; neither wakes a peer that is polling (docs/protocol.md §6.1). Each polls
    /// about two thirds of every 300 µs period, so a vCPU that the host wakes up to 200 µs late
    /// still publishes and answers on time (the measurements behind the 200 µs are in
    /// docs/bench/README.md). The supervisor shares CPU 0 as SCHED_OTHER.
    /// Needs CPUs the host does not take away: a virtual CPU frozen for 30 ms is 100 misses in
    /// a row.
    pub fn realtime_split_cpus() -> Self {
        Self {
            plant_cpu: Some(1),
            controller_cpu: Some(0),
            supervisor_cpu: Some(0),
            plant_priority: Some(80),
            controller_priority: Some(70),
            spin_us: Some(150),
            lock_memory: Some(true),
            wake_early_us: Some(200),
            controller_wake_early_us: Some(200),
            poll: Some(Poll::Spin),
        }
    }

    /// Plant and controller on CPU 1 at the same SCHED_FIFO priority, handing the CPU to each
    /// other with `sched_yield` (`poll = "yield"`): the plant wakes 80 µs early and yields while
    /// it waits for the reply, the controller sleeps until 50 µs before each deadline and yields
    /// while it waits for the state and once after each reply; no notifications. Two context
    /// switches per round trip instead of two notifications and two wake-ups, and, as in the
    /// default, a host that freezes CPU 1 stalls both together. The plant cannot preempt its
    /// controller here: a reply computed for longer than the budget delays the plant's next wake
    /// as well (it is still a miss). The supervisor on CPU 0.
    pub fn realtime_one_cpu_yield() -> Self {
        Self {
            controller_priority: Some(80),
            spin_us: Some(150),
            poll: Some(Poll::Yield),
            ..Self::realtime_default()
        }
    }

    /// Lockstep default, the highest cycle rate: one CPU each, busy-polling before blocking.
    pub fn lockstep_default() -> Self {
        Self {
            plant_cpu: Some(0),
            controller_cpu: Some(1),
            supervisor_cpu: Some(-1),
            plant_priority: Some(0),
            controller_priority: Some(0),
            spin_us: Some(200),
            lock_memory: Some(false),
            wake_early_us: Some(0),
            controller_wake_early_us: Some(-1),
            poll: Some(Poll::Spin),
        }
    }

    fn fill(&mut self, d: Layout) {
        self.plant_cpu = self.plant_cpu.or(d.plant_cpu);
        self.controller_cpu = self.controller_cpu.or(d.controller_cpu);
        self.supervisor_cpu = self.supervisor_cpu.or(d.supervisor_cpu);
        self.plant_priority = self.plant_priority.or(d.plant_priority);
        self.controller_priority = self.controller_priority.or(d.controller_priority);
        self.spin_us = self.spin_us.or(d.spin_us);
        self.lock_memory = self.lock_memory.or(d.lock_memory);
        self.wake_early_us = self.wake_early_us.or(d.wake_early_us);
        self.controller_wake_early_us =
            self.controller_wake_early_us.or(d.controller_wake_early_us);
        self.poll = self.poll.or(d.poll);
    }

    /// Checks one mode's layout; `section` names it in errors (`loop.realtime`, `loop.lockstep`),
    /// `ts_s` is the (already validated) control period, which bounds `wake_early_us`: waking more
    /// than a period before the deadline would wake before the previous tick.
    fn validate(&self, section: &str, ts_s: f64) -> Result<(), ConfigError> {
        for (k, v) in [
            ("plant_cpu", self.plant_cpu),
            ("controller_cpu", self.controller_cpu),
            ("supervisor_cpu", self.supervisor_cpu),
        ] {
            let v = v.unwrap_or(-1);
            if !(-1..=1023).contains(&v) {
                return Err(range(
                    &format!("{section}.{k}"),
                    v,
                    "-1 (not pinned) or a CPU index 0..=1023",
                ));
            }
        }
        for (k, v) in [
            ("plant_priority", self.plant_priority),
            ("controller_priority", self.controller_priority),
        ] {
            let v = v.unwrap_or(0);
            if !(0..=99).contains(&v) {
                return Err(range(
                    &format!("{section}.{k}"),
                    v,
                    "0 (SCHED_OTHER) or a SCHED_FIFO priority 1..=99",
                ));
            }
        }
        let spin = self.spin_us.unwrap_or(0);
        if spin > 1_000_000 {
            return Err(range(
                &format!("{section}.spin_us"),
                spin,
                "0 <= spin_us <= 1000000 us",
            ));
        }
        let wake = self.wake_early_us.unwrap_or(0);
        let period_us = ts_s * 1e6;
        if f64::from(wake) > period_us {
            return Err(range(
                &format!("{section}.wake_early_us"),
                wake,
                &format!("0 <= wake_early_us <= Ts = {period_us} us"),
            ));
        }
        let cwake = self.controller_wake_early_us.unwrap_or(-1);
        if cwake < -1 || f64::from(cwake) > period_us {
            return Err(range(
                &format!("{section}.controller_wake_early_us"),
                cwake,
                &format!(
                    "-1 (wait for the notification) or 0 <= controller_wake_early_us <= Ts = {period_us} us"
                ),
            ));
        }
        self.check_yield(section)
    }

    /// `poll = "yield"` hands the CPU over only to a peer of the same priority on the same CPU:
    /// anywhere else a yield returns at once, or never reaches a peer of lower priority, which
    /// would then starve behind the polling plant.
    fn check_yield(&self, section: &str) -> Result<(), ConfigError> {
        if self.poll != Some(Poll::Yield) {
            return Ok(());
        }
        let (pc, cc) = (
            self.plant_cpu.unwrap_or(-1),
            self.controller_cpu.unwrap_or(-1),
        );
        let (pp, cp) = (
            self.plant_priority.unwrap_or(0),
            self.controller_priority.unwrap_or(0),
        );
        if pc < 0 || pc != cc || pp != cp {
            return Err(range(
                &format!("{section}.poll"),
                "\"yield\"",
                &format!(
                    "\"yield\" needs plant_cpu = controller_cpu (pinned) and plant_priority = controller_priority; here plant_cpu {pc}, controller_cpu {cc}, plant_priority {pp}, controller_priority {cp} (or poll = \"spin\")"
                ),
            ));
        }
        Ok(())
    }

    /// The controller's lead before each deadline in realtime, ns; None: it waits for the
    /// notification instead.
    pub fn controller_lead_ns(&self) -> Option<u64> {
        let us = u64::try_from(self.controller_wake_early_us?).ok()?;
        Some(us * 1000)
    }

    /// This layout with `wake_early_us` at most one period of `ts_s` (µs), so a default never
    /// fails the check of [`Layout::validate`] at a short period the user chose. A non-finite or
    /// out-of-range `ts_s` leaves it as is (the period's own check reports that).
    fn wake_early_within(mut self, ts_s: f64) -> Self {
        let period_us = ts_s * 1e6;
        if let Some(w) = self.wake_early_us
            && period_us.is_finite()
            && period_us >= 0.0
            && f64::from(w) > period_us
        {
            // Truncation is the point: the largest whole µs within the period.
            self.wake_early_us = Some(period_us as u32);
        }
        if let Some(w) = self.controller_wake_early_us
            && period_us.is_finite()
            && period_us >= 0.0
            && f64::from(w) > period_us
        {
            self.controller_wake_early_us = Some(period_us as i32);
        }
        self
    }

    /// The CPU of a role as an Option (−1 → None).
    pub fn cpu(v: Option<i32>) -> Option<usize> {
        v.and_then(|c| usize::try_from(c).ok())
    }
}

/// `[loop]`: timing of the control loop and the process layout per mode.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LoopSection {
    /// Control period Ts, s.
    #[serde(default = "default_ts")]
    pub ts_s: f64,
    /// Realtime: how long after publishing a state the plant waits for its torque, µs.
    #[serde(default = "default_budget")]
    pub torque_budget_us: u32,
    /// A peer silent this long is a fault (lockstep, and the controller's wait for states), ms.
    #[serde(default = "default_silence")]
    pub silence_timeout_ms: u32,
    #[serde(default)]
    pub realtime: Layout,
    #[serde(default)]
    pub lockstep: Layout,
}

fn default_ts() -> f64 {
    3e-4
}
fn default_budget() -> u32 {
    150
}
fn default_silence() -> u32 {
    2000
}

impl Default for LoopSection {
    fn default() -> Self {
        Self {
            ts_s: default_ts(),
            torque_budget_us: default_budget(),
            silence_timeout_ms: default_silence(),
            realtime: Layout::default(),
            lockstep: Layout::default(),
        }
    }
}

/// A whole scenario file. Sections other than `[scenario]` are optional.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RunConfig {
    /// Scenario name (run folders and reports use it); defaults to the file stem.
    #[serde(default)]
    pub name: String,
    /// Free text for reports.
    #[serde(default, skip_serializing_if = "String::is_empty")]
    pub description: String,
    pub scenario: ScenarioSection,
    #[serde(default)]
    pub plant: PlantSection,
    #[serde(default)]
    pub controller: ControllerSection,
    #[serde(default, rename = "loop")]
    pub loop_: LoopSection,
    #[serde(default)]
    pub sensor: SensorSection,
    #[serde(default)]
    pub faults: FaultSection,
    #[serde(default)]
    pub record: RecordSection,
}

/// `[record]`: which per-tick files a run writes. Both are on by default: every tick of every law
/// on disk, which is what replay and offline analysis need. A soak that only watches timing can
/// turn them off: the summary, report, histograms, interval logs and figures do not depend on
/// them, and disk no longer grows with the run's length (≈ 630 B a tick for the trace, ≈ 106 B for
/// the timing file).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RecordSection {
    /// Write `trace.csv` (joint states, torques, errors and estimates of every tick). Without it a
    /// run cannot be replayed.
    pub trace: bool,
    /// Write `<law>.timing.csv` (the raw clock stamps of every tick) in realtime and lockstep runs.
    pub timing_csv: bool,
}

impl Default for RecordSection {
    fn default() -> Self {
        Self {
            trace: true,
            timing_csv: true,
        }
    }
}

/// Largest accepted TDE delay ℓ (`controller.tde_delay_samples`), ticks. The controller keeps ℓ
/// past (acceleration, torque) pairs.
pub const MAX_TDE_DELAY: u32 = 10_000;

/// Largest accepted transport delay d (`plant.transport_delay_samples`), ticks. The plant's drives
/// keep d commands in flight. Separate from [`MAX_TDE_DELAY`]: the two delays are different
/// things (one in the controller's estimate, one on the wire) and share a value by coincidence.
pub const MAX_TRANSPORT_DELAY: u32 = 10_000;

/// Largest accepted `plant.transport_delay_us`, µs (1 s).
pub const MAX_TRANSPORT_DELAY_US: f64 = 1e6;

/// Largest accepted `plant.substeps`; the period bounds it further (RK4 step ≥ 1 µs).
pub const MAX_SUBSTEPS: u32 = 1000;

/// Largest config or sweep file read, bytes (1 MiB). A scenario file is a few hundred bytes.
pub const MAX_FILE_BYTES: u64 = 1 << 20;

/// Echoed user text (a value, a quoted part of a parser message) is cut to this many characters.
pub const MAX_ECHO_CHARS: usize = 60;

/// Longest parser message echoed, characters (the rest is cut with `…`).
const MAX_MESSAGE_CHARS: usize = 300;

/// Longest path echoed whole, characters (a longer one keeps its start and end).
const MAX_PATH_CHARS: usize = 160;

/// What a scenario or sweep `name` may be: it names a folder under `runs/`.
pub const NAME_RULE: &str = "1 to 64 characters from A-Z a-z 0-9 . _ -, not starting with . or -";

/// Pushes `c`, escaped as `{:?}` would when it is a control or format character (newline,
/// right-to-left mark, …), so that no echoed text breaks the line or reorders it. With `quoted`,
/// `"` and `\` are escaped too (the text is shown between our own quotes).
fn push_escaped(out: &mut String, c: char, quoted: bool) {
    let plain = matches!(c, '\'' | '"' | '\\') && !quoted;
    if plain || c == '\'' {
        out.push(c);
    } else {
        out.extend(c.escape_debug());
    }
}

/// `s` escaped (see [`push_escaped`]) and cut to `max` characters of the original with `…`.
fn escape_cut(s: &str, max: usize, quoted: bool) -> String {
    let mut out = String::new();
    for (i, c) in s.chars().enumerate() {
        if i == max {
            out.push('…');
            break;
        }
        push_escaped(&mut out, c, quoted);
    }
    out
}

/// A user string as echoed in errors: quoted, escaped like `{:?}` (control and format
/// characters visible), cut to [`MAX_ECHO_CHARS`] characters with `…`.
pub fn show_str(s: &str) -> String {
    format!("\"{}\"", escape_cut(s, MAX_ECHO_CHARS, true))
}

/// A path as echoed in errors: control and format characters escaped; a very long one keeps
/// its start and its end around `…`.
pub fn show_path(p: &Path) -> String {
    let s = p.to_string_lossy();
    let n = s.chars().count();
    if n <= MAX_PATH_CHARS {
        return escape_cut(&s, n, false);
    }
    let half = MAX_PATH_CHARS / 2;
    let tail: String = s.chars().skip(n - half).collect();
    format!(
        "{}{}",
        escape_cut(&s, half, false),
        escape_cut(&tail, half, false)
    )
}

/// A number as echoed in errors: plain between 1e-4 and 1e6, else in exponent form (`1e308`,
/// not 309 digits).
pub fn show_num(x: f64) -> String {
    if x != 0.0 && x.is_finite() && !(1e-4..1e6).contains(&x.abs()) {
        format!("{x:e}")
    } else {
        x.to_string()
    }
}

/// A parser message made safe to echo on one line: control and format characters escaped,
/// every quoted part (between backticks or double quotes, which is where the parser and serde
/// put the offending text) cut to [`MAX_ECHO_CHARS`], and the whole to a few hundred characters.
pub fn clean_message(msg: &str) -> String {
    let mut out = String::new();
    let mut chars = msg.trim_end().chars().peekable();
    while let Some(c) = chars.next() {
        if c == '`' || c == '"' {
            // A quoted part: up to the matching delimiter (a `"` part may escape it with `\`).
            let mut part = String::new();
            let mut closed = false;
            while let Some(d) = chars.next() {
                if d == c {
                    closed = true;
                    break;
                }
                part.push(d);
                if c == '"'
                    && d == '\\'
                    && let Some(e) = chars.next()
                {
                    part.push(e);
                }
            }
            out.push(c);
            out.push_str(&escape_cut(&part, MAX_ECHO_CHARS, false));
            if closed {
                out.push(c);
            }
        } else if c == '\n' {
            out.push_str("; ");
        } else {
            push_escaped(&mut out, c, false);
        }
    }
    if out.chars().count() > MAX_MESSAGE_CHARS {
        out = out.chars().take(MAX_MESSAGE_CHARS).collect();
        out.push('…');
    }
    out
}

/// Where a TOML error is: 1-based line and column (in characters) of the start of its span.
pub fn toml_error_position(text: &str, e: &toml::de::Error) -> Option<(usize, usize)> {
    let start = e.span()?.start.min(text.len());
    let before = text.as_bytes().get(..start)?;
    let line = before.iter().filter(|&&b| b == b'\n').count() + 1;
    let line_start = before
        .iter()
        .rposition(|&b| b == b'\n')
        .map_or(0, |i| i + 1);
    let column = String::from_utf8_lossy(&before[line_start..])
        .chars()
        .count()
        + 1;
    Some((line, column))
}

/// A TOML error on one line: the parser's message (cleaned, see [`clean_message`]) and where,
/// without the snippet of the offending line.
pub fn toml_error_line(text: &str, e: &toml::de::Error) -> String {
    let at = toml_error_position(text, e)
        .map(|(l, c)| format!(" at line {l}, column {c}"))
        .unwrap_or_default();
    format!("{}{at}", clean_message(e.message()))
}

/// Reads a config-like text file: only a regular file (a FIFO would block, a device such as
/// `/dev/zero` never ends), at most [`MAX_FILE_BYTES`], UTF-8 (see [`crate::files`]). The error is
/// the reason alone; the caller names the file.
pub fn read_text_file(path: &Path) -> Result<String, String> {
    crate::files::read_text(path, MAX_FILE_BYTES, "a config file")
}

/// Whether `name` may name a run folder: see [`NAME_RULE`].
pub fn name_is_valid(name: &str) -> bool {
    (1..=64).contains(&name.len())
        && !name.starts_with(['.', '-'])
        && name
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || matches!(b, b'.' | b'_' | b'-'))
}

/// The default name from a file stem: every character outside [`NAME_RULE`] becomes `_`, a
/// leading `.` or `-` too, cut to 64 characters (`scenario` if nothing is left).
fn name_from_stem(stem: &str) -> String {
    let mut name: String = stem
        .chars()
        .take(64)
        .enumerate()
        .map(|(i, c)| {
            let ok = c.is_ascii_alphanumeric() || matches!(c, '.' | '_' | '-');
            if ok && !(i == 0 && matches!(c, '.' | '-')) {
                c
            } else {
                '_'
            }
        })
        .collect();
    if name.is_empty() {
        name = "scenario".into();
    }
    name
}

fn range(key: &str, value: impl fmt::Display, allowed: &str) -> ConfigError {
    let value = value.to_string();
    ConfigError::Range {
        key: key.into(),
        value: if value.chars().count() > MAX_ECHO_CHARS {
            escape_cut(&value, MAX_ECHO_CHARS, false)
        } else {
            value
        },
        allowed: allowed.into(),
    }
}

/// A process command: empty (the built-in process), or a program and its arguments, each a
/// non-empty string without NUL of at most 4096 bytes.
fn check_command(key: &str, cmd: &[String]) -> Result<(), ConfigError> {
    match cmd
        .iter()
        .find(|a| a.is_empty() || a.contains('\0') || a.len() > 4096)
    {
        Some(bad) => Err(range(
            key,
            show_str(bad),
            "a program and its arguments, each a non-empty string of at most 4096 bytes without NUL",
        )),
        None => Ok(()),
    }
}

fn check(key: &str, v: f64, ok: bool, allowed: &str) -> Result<(), ConfigError> {
    if v.is_finite() && ok {
        Ok(())
    } else {
        Err(range(key, show_num(v), allowed))
    }
}

/// Seconds for an allowed range: rounded to 1 ns, so `(N − 1)·Ts` reads `0.7997`, not
/// `0.7997000000000001`.
fn secs(x: f64) -> String {
    show_num((x * 1e9).round() / 1e9)
}

/// The longest hold, s: a day (a run streams, so only the disk bounds its length).
pub const MAX_HOLD_S: f64 = 86_400.0;

impl ScenarioSection {
    /// `[scenario]`: the hold, and the segments (only, and at least one, with `custom`).
    fn validate(&self) -> Result<(), ConfigError> {
        check(
            "scenario.hold_s",
            self.hold_s,
            (0.0..=MAX_HOLD_S).contains(&self.hold_s),
            "0 <= hold_s <= 86400 s (24 h)",
        )?;
        match (self.path, self.segments.is_empty()) {
            (PathKind::Custom, true) => {
                return Err(range(
                    "scenario.segments",
                    "[]",
                    "at least one segment when path = \"custom\"",
                ));
            }
            (PathKind::Custom, false) => {}
            (_, false) => {
                return Err(range(
                    "scenario.segments",
                    format!("[{} segments]", self.segments.len()),
                    "segments are only allowed with path = \"custom\"",
                ));
            }
            _ => {}
        }
        for (i, seg) in self.segments.iter().enumerate() {
            let key = |k: &str| format!("scenario.segments[{i}].{k}");
            for (k, p) in [("from", seg.from), ("to", seg.to)] {
                for v in p {
                    check(&key(k), v, v.abs() <= 2.0, "coordinates within ±2 m")?;
                }
            }
            check(
                &key("apex_m"),
                seg.apex_m,
                seg.apex_m.abs() <= 1.0,
                "-1 <= apex_m <= 1 m",
            )?;
            check(
                &key("duration_s"),
                seg.duration_s,
                seg.duration_s > 0.0 && seg.duration_s <= 3600.0,
                "0 < duration_s <= 3600 s",
            )?;
        }
        Ok(())
    }
}

impl PlantSection {
    /// `[plant]`: torque limit, integrator steps, transport delay, payload step.
    fn validate(&self) -> Result<(), ConfigError> {
        check(
            "plant.tau_max_nm",
            self.tau_max_nm,
            self.tau_max_nm > 0.0 && self.tau_max_nm <= 1e4,
            "0 < tau_max_nm <= 10000 N m",
        )?;
        if !(1..=MAX_SUBSTEPS).contains(&self.substeps) {
            return Err(range(
                "plant.substeps",
                self.substeps,
                &format!("1 <= substeps <= {MAX_SUBSTEPS}"),
            ));
        }
        if self.transport_delay_samples > MAX_TRANSPORT_DELAY {
            return Err(range(
                "plant.transport_delay_samples",
                self.transport_delay_samples,
                &format!("0 <= transport_delay_samples <= {MAX_TRANSPORT_DELAY} ticks"),
            ));
        }
        check_command("plant.command", &self.command)?;
        check(
            "plant.transport_delay_us",
            self.transport_delay_us,
            (0.0..=MAX_TRANSPORT_DELAY_US).contains(&self.transport_delay_us),
            &format!("0 <= transport_delay_us <= {MAX_TRANSPORT_DELAY_US} µs"),
        )?;
        check(
            "plant.payload_step_kg",
            self.payload_step_kg,
            (0.0..=10.0).contains(&self.payload_step_kg),
            "0 <= payload_step_kg <= 10 kg (0: no step)",
        )?;
        if let Some(t) = self.payload_step_at_s {
            check(
                "plant.payload_step_at_s",
                t,
                (0.0..=3600.0).contains(&t),
                "0 <= payload_step_at_s <= 3600 s",
            )?;
        }
        Ok(())
    }
}

impl LoopSection {
    /// `[loop]`: the period first (the budget and both layouts are bounded by it), then the
    /// torque budget, the silence timeout and the layout of each process mode.
    fn validate(&self) -> Result<(), ConfigError> {
        let ts = self.ts_s;
        check(
            "loop.ts_s",
            ts,
            (1e-5..=0.1).contains(&ts),
            "1e-5 <= ts_s <= 0.1 s",
        )?;
        let budget = self.torque_budget_us;
        if budget == 0 || f64::from(budget) * 1e-6 >= ts {
            return Err(range(
                "loop.torque_budget_us",
                budget,
                &format!("0 < torque_budget_us < Ts = {} us", ts * 1e6),
            ));
        }
        let silence = self.silence_timeout_ms;
        if !(10..=600_000).contains(&silence) {
            return Err(range(
                "loop.silence_timeout_ms",
                silence,
                "10 <= silence_timeout_ms <= 600000 ms",
            ));
        }
        self.realtime.validate("loop.realtime", ts)?;
        self.lockstep.validate("loop.lockstep", ts)
    }
}

impl SensorSection {
    /// `[sensor]`: noise levels and encoder resolution.
    fn validate(&self) -> Result<(), ConfigError> {
        check(
            "sensor.q_noise_std_rad",
            self.q_noise_std_rad,
            (0.0..=0.1).contains(&self.q_noise_std_rad),
            "0 <= q_noise_std_rad <= 0.1 rad",
        )?;
        check(
            "sensor.qd_noise_std_rad_s",
            self.qd_noise_std_rad_s,
            (0.0..=10.0).contains(&self.qd_noise_std_rad_s),
            "0 <= qd_noise_std_rad_s <= 10 rad/s",
        )?;
        if self.encoder_counts_per_rev != 0 && self.encoder_counts_per_rev < 16 {
            return Err(range(
                "sensor.encoder_counts_per_rev",
                self.encoder_counts_per_rev,
                "0 (ideal) or 16..=4294967295 counts per revolution",
            ));
        }
        Ok(())
    }
}

impl FaultSection {
    /// `[faults]`: silence window, safe stop, brake.
    fn validate(&self) -> Result<(), ConfigError> {
        if !(1..=1_000_000).contains(&self.controller_silence_ticks) {
            return Err(range(
                "faults.controller_silence_ticks",
                self.controller_silence_ticks,
                "1 <= controller_silence_ticks <= 1000000 ticks",
            ));
        }
        if self.safe_stop_ms > 60_000 {
            return Err(range(
                "faults.safe_stop_ms",
                self.safe_stop_ms,
                "0 <= safe_stop_ms <= 60000 ms",
            ));
        }
        check(
            "faults.brake_damping_nm_s",
            self.brake_damping_nm_s,
            (0.0..=1000.0).contains(&self.brake_damping_nm_s),
            "0 <= brake_damping_nm_s <= 1000 N m s/rad",
        )
    }
}

impl ControllerSection {
    /// The constants: the preset with this section's overrides applied.
    fn params(&self) -> ControllerParams {
        let p = ControllerParams::preset(self.preset);
        ControllerParams {
            m_bar: self.m_bar.unwrap_or(p.m_bar),
            kp: self.kp.unwrap_or(p.kp),
            kd: self.kd.unwrap_or(p.kd),
            ks: self.ks.unwrap_or(p.ks),
            phi: self.phi.unwrap_or(p.phi),
            k1: self.k1.unwrap_or(p.k1),
            k2: self.k2.unwrap_or(p.k2),
            pid_p: self.pid_p.unwrap_or(p.pid_p),
            pid_i: self.pid_i.unwrap_or(p.pid_i),
            pid_d: self.pid_d.unwrap_or(p.pid_d),
        }
    }

    /// `[controller]`: compute delay, the law list, the TDE delay, and the resolved constants.
    fn validate(&self) -> Result<(), ConfigError> {
        if self.compute_delay_us > 1_000_000 {
            return Err(range(
                "controller.compute_delay_us",
                self.compute_delay_us,
                "0 <= compute_delay_us <= 1000000 us",
            ));
        }
        if self.laws.is_empty() {
            return Err(range(
                "controller.laws",
                "[]",
                "at least one of tdc, tde-is, tdc-is-sta, pid",
            ));
        }
        for (i, l) in self.laws.iter().enumerate() {
            if self.laws[..i].contains(l) {
                return Err(range("controller.laws", l, "each law at most once"));
            }
        }
        check_command("controller.command", &self.command)?;
        if !(1..=MAX_TDE_DELAY).contains(&self.tde_delay_samples) {
            return Err(range(
                "controller.tde_delay_samples",
                self.tde_delay_samples,
                &format!("1 <= tde_delay_samples <= {MAX_TDE_DELAY} ticks"),
            ));
        }
        let k = self.params();
        check(
            "controller.m_bar",
            k.m_bar,
            k.m_bar > 0.0 && k.m_bar <= 100.0,
            "0 < m_bar <= 100 kg m^2",
        )?;
        for (key, v) in [
            ("controller.kp", k.kp),
            ("controller.kd", k.kd),
            ("controller.ks", k.ks),
            ("controller.phi", k.phi),
            ("controller.k1", k.k1),
            ("controller.k2", k.k2),
            ("controller.pid_p", k.pid_p),
            ("controller.pid_i", k.pid_i),
            ("controller.pid_d", k.pid_d),
        ] {
            check(
                key,
                v,
                (0.0..=1e9).contains(&v),
                "a finite number, 0 <= value <= 1e9",
            )?;
        }
        Ok(())
    }
}

impl RunConfig {
    /// Parses, fills the preset, and validates. `path` only labels errors.
    pub fn from_toml_str(text: &str, path: Option<&Path>) -> Result<Self, ConfigError> {
        let mut cfg: RunConfig = toml::from_str(text).map_err(|e| ConfigError::Parse {
            path: path.map(show_path),
            message: clean_message(e.message()),
            position: toml_error_position(text, &e),
        })?;
        if cfg.name.is_empty() {
            cfg.name = path.and_then(|p| p.file_stem()).map_or_else(
                || "scenario".into(),
                |s| name_from_stem(&s.to_string_lossy()),
            );
        }
        cfg.resolve_preset();
        let ts = cfg.loop_.ts_s;
        cfg.loop_
            .realtime
            .fill(Layout::realtime_default().wake_early_within(ts));
        cfg.loop_
            .lockstep
            .fill(Layout::lockstep_default().wake_early_within(ts));
        cfg.validate()?;
        Ok(cfg)
    }

    /// Reads and parses a file: a regular file of at most [`MAX_FILE_BYTES`] (see
    /// [`read_text_file`]).
    pub fn from_file(path: &Path) -> Result<Self, ConfigError> {
        let text = read_text_file(path).map_err(|reason| ConfigError::Read {
            path: show_path(path),
            reason,
        })?;
        Self::from_toml_str(&text, Some(path))
    }

    /// The resolved config as TOML: every constant explicit; parses back to `self`.
    pub fn to_toml_string(&self) -> String {
        toml::to_string_pretty(self).expect("config serialises")
    }

    /// The controller constants: the preset with the file's overrides applied.
    pub fn controller_params(&self) -> ControllerParams {
        self.controller.params()
    }

    /// Writes the preset's values into every override that is not set, so the config is explicit.
    fn resolve_preset(&mut self) {
        let p = self.controller_params();
        let c = &mut self.controller;
        c.m_bar = Some(p.m_bar);
        c.kp = Some(p.kp);
        c.kd = Some(p.kd);
        c.ks = Some(p.ks);
        c.phi = Some(p.phi);
        c.k1 = Some(p.k1);
        c.k2 = Some(p.k2);
        c.pid_p = Some(p.pid_p);
        c.pid_i = Some(p.pid_i);
        c.pid_d = Some(p.pid_d);
    }

    /// Checks every value against its allowed range, one section at a time.
    pub fn validate(&self) -> Result<(), ConfigError> {
        if !name_is_valid(&self.name) {
            return Err(ConfigError::Range {
                key: "name".into(),
                value: show_str(&self.name),
                allowed: NAME_RULE.into(),
            });
        }
        self.scenario.validate()?;
        self.plant.validate()?;
        self.loop_.validate()?;
        self.sensor.validate()?;
        self.faults.validate()?;
        self.controller.validate()?;
        self.validate_timing()
    }

    /// The keys bounded by the (already validated) control period Ts: every custom segment lasts
    /// at least one period (so the run has at least one tick, and no segment falls between two
    /// samples); the RK4 step Ts/substeps is at least 1 µs (the plant must keep up in realtime);
    /// a payload step falls within the run.
    fn validate_timing(&self) -> Result<(), ConfigError> {
        let ts = self.loop_.ts_s;
        for (i, seg) in self.scenario.segments.iter().enumerate() {
            if seg.duration_s < ts {
                return Err(range(
                    &format!("scenario.segments[{i}].duration_s"),
                    show_num(seg.duration_s),
                    &format!(
                        "Ts = {} s <= duration_s <= 3600 s (a segment lasts at least one control period)",
                        secs(ts)
                    ),
                ));
            }
        }
        // floor(Ts / 1 µs), tolerant of round-off (3e-4 s is 300 steps, not 299).
        let max_substeps = ((ts * 1e6 + 1e-6).floor() as u32).min(MAX_SUBSTEPS);
        if self.plant.substeps > max_substeps {
            return Err(range(
                "plant.substeps",
                self.plant.substeps,
                &format!(
                    "1 <= substeps <= {max_substeps} for ts_s = {} s (the RK4 step ts_s/substeps must be >= 1 us)",
                    secs(ts)
                ),
            ));
        }
        if let Some(t) = self.plant.payload_step_at_s {
            let end = self.motion_duration_s() + self.scenario.hold_s;
            let n = self.ticks(self.motion_duration_s());
            if step_tick(t, ts) >= n {
                return Err(range(
                    "plant.payload_step_at_s",
                    show_num(t),
                    &format!(
                        "0 <= payload_step_at_s <= {} s, the start of the last control period (motion + hold = {} s)",
                        secs(n.saturating_sub(1) as f64 * ts),
                        secs(end)
                    ),
                ));
            }
        }
        Ok(())
    }

    /// Motion duration T of the scenario, s.
    pub fn motion_duration_s(&self) -> f64 {
        self.scenario
            .path
            .paper_duration_s()
            .unwrap_or_else(|| self.scenario.segments.iter().map(|s| s.duration_s).sum())
    }

    /// The control tick of the payload step, if any: the first instant k·Ts ≥ the configured
    /// time (default T/2; docs/delta-robot.md §4.3: k = 1334, 334, 2000 for S1, S2, S3).
    pub fn payload_step_tick(&self) -> Option<u64> {
        (self.plant.payload_step_kg > 0.0).then(|| {
            let t = self
                .plant
                .payload_step_at_s
                .unwrap_or(self.motion_duration_s() / 2.0);
            step_tick(t, self.loop_.ts_s)
        })
    }

    /// The control period Ts, ns.
    pub fn ts_ns(&self) -> u64 {
        (self.loop_.ts_s * 1e9).round() as u64
    }

    /// The transport delay D = d·Ts + `transport_delay_us`, ns.
    pub fn transport_delay_ns(&self) -> u64 {
        u64::from(self.plant.transport_delay_samples) * self.ts_ns()
            + (self.plant.transport_delay_us * 1e3).round() as u64
    }

    /// Number of control ticks after tick 0 for the whole run: round((T + hold)/Ts).
    pub fn ticks(&self, motion_duration_s: f64) -> u64 {
        ((motion_duration_s + self.scenario.hold_s) / self.loop_.ts_s).round() as u64
    }
}

/// The first control tick k with k·Ts ≥ t.
fn step_tick(t: f64, ts: f64) -> u64 {
    let k = (t / ts).ceil();
    // Guard against round-off pushing an exact multiple one tick up.
    if ((k - 1.0) * ts - t).abs() < 1e-12 * t.max(1.0) {
        (k - 1.0) as u64
    } else {
        k as u64
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::PathBuf;

    const MIN: &str = "[scenario]\npath = \"s1\"\n";

    /// Every run config the repo ships loads and validates (the sweep and Slurm files have their
    /// own schema); `configs/soak-split.toml` is exactly the split-CPU layout docs/performance.md measures.
    #[test]
    fn shipped_run_configs_load_and_soak_split_is_the_split_layout() {
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../configs");
        let mut seen = 0;
        for dir in [root.clone(), root.join("paper")] {
            for e in std::fs::read_dir(&dir).unwrap().flatten() {
                let path = e.path();
                let text = std::fs::read_to_string(&path).unwrap_or_default();
                let sweep = text
                    .lines()
                    .any(|l| l.starts_with("[slurm]") || l.starts_with("scenarios = "));
                if path.extension().is_some_and(|x| x == "toml") && !sweep {
                    // from_toml_str validates too.
                    RunConfig::from_toml_str(&text, Some(&path))
                        .unwrap_or_else(|e| panic!("{}: {e}", path.display()));
                    seen += 1;
                }
            }
        }
        assert!(seen >= 9, "{seen} configs");
        let split = root.join("soak-split.toml");
        let c = RunConfig::from_toml_str(&std::fs::read_to_string(&split).unwrap(), Some(&split))
            .unwrap();
        assert_eq!(c.loop_.realtime, Layout::realtime_split_cpus());
        let one = root.join("soak-yield.toml");
        let c =
            RunConfig::from_toml_str(&std::fs::read_to_string(&one).unwrap(), Some(&one)).unwrap();
        assert_eq!(c.loop_.realtime, Layout::realtime_one_cpu_yield());
    }

    #[test]
    fn yielding_needs_plant_and_controller_on_one_cpu_at_one_priority() {
        let yield_with = |extra: &str| {
            RunConfig::from_toml_str(
                &format!("{MIN}[loop.realtime]\npoll = \"yield\"\n{extra}"),
                None,
            )
        };
        // The default layout has the plant above the controller: a yield would never reach it.
        let e = yield_with("").unwrap_err().to_string();
        assert!(
            e.contains("`loop.realtime.poll` = \"yield\"")
                && e.contains("plant_priority 80, controller_priority 70"),
            "{e}"
        );
        let e = yield_with("controller_priority = 80\ncontroller_cpu = 0\n")
            .unwrap_err()
            .to_string();
        assert!(e.contains("plant_cpu 1, controller_cpu 0"), "{e}");
        let e = yield_with("controller_priority = 80\nplant_cpu = -1\ncontroller_cpu = -1\n")
            .unwrap_err()
            .to_string();
        assert!(e.contains("plant_cpu -1, controller_cpu -1"), "{e}");
        let c = yield_with("controller_priority = 80\n").unwrap();
        assert_eq!(c.loop_.realtime.poll, Some(Poll::Yield));
        assert_eq!(
            RunConfig::from_toml_str(&c.to_toml_string(), None).unwrap(),
            c,
            "the resolved config round-trips with its poll"
        );
        let e = RunConfig::from_toml_str(&format!("{MIN}[loop.lockstep]\npoll = \"nap\"\n"), None)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("nap") && e.contains("spin") && e.contains("yield"),
            "{e}"
        );
        assert!(
            Layout::realtime_one_cpu_yield()
                .validate("loop.realtime", 3e-4)
                .is_ok()
        );
        assert_eq!(Layout::realtime_default().poll, Some(Poll::Spin));
    }

    #[test]
    fn minimal_file_gets_matched_preset_and_all_laws() {
        let c = RunConfig::from_toml_str(MIN, Some(Path::new("configs/x.toml"))).unwrap();
        assert_eq!(c.name, "x");
        assert_eq!(c.controller.laws, Law::ALL.to_vec());
        assert_eq!(
            c.controller_params(),
            ControllerParams::preset(Preset::Matched)
        );
        assert_eq!(c.controller_params().m_bar, 0.03);
    }

    #[test]
    fn override_is_key_by_key() {
        let c = RunConfig::from_toml_str(
            &format!("{MIN}[controller]\npreset = \"paper\"\nk1 = 50.0\n"),
            None,
        )
        .unwrap();
        let p = c.controller_params();
        assert_eq!(p.k1, 50.0);
        assert_eq!(p.m_bar, 3e-4);
        assert_eq!(p.phi, 100.0);
    }

    #[test]
    fn resolved_config_round_trips() {
        let c = RunConfig::from_toml_str(
            &format!("{MIN}[controller]\npreset = \"paper\"\nkp = 900.0\n"),
            None,
        )
        .unwrap();
        let again = RunConfig::from_toml_str(&c.to_toml_string(), None).unwrap();
        assert_eq!(c, again);
    }

    #[test]
    fn unknown_key_is_named() {
        let e =
            RunConfig::from_toml_str(&format!("{MIN}[controller]\nkpp = 1.0\n"), None).unwrap_err();
        let msg = e.to_string();
        assert!(
            msg.contains("kpp") && msg.contains("expected one of"),
            "{msg}"
        );
    }

    #[test]
    fn record_writes_every_per_tick_file_unless_told_not_to() {
        let c = RunConfig::from_toml_str(MIN, None).unwrap();
        assert_eq!(
            c.record,
            RecordSection {
                trace: true,
                timing_csv: true
            }
        );
        let c = RunConfig::from_toml_str(&format!("{MIN}[record]\ntrace = false\n"), None).unwrap();
        assert!(!c.record.trace && c.record.timing_csv);
        // The resolved config (what the run folder keeps) says so, and reads back the same.
        assert!(
            c.to_toml_string()
                .contains("[record]\ntrace = false\ntiming_csv = true")
        );
        assert_eq!(
            RunConfig::from_toml_str(&c.to_toml_string(), None).unwrap(),
            c
        );
        let e = err(&format!("{MIN}[record]\ntraces = false\n"));
        assert!(
            e.contains("unknown field `traces`, expected `trace` or `timing_csv`"),
            "{e}"
        );
        let e = err(&format!("{MIN}[record]\ntrace = \"no\"\n"));
        assert!(
            e.contains("expected a boolean") && e.contains("line 4"),
            "{e}"
        );
    }

    #[test]
    fn out_of_range_names_key_value_and_range() {
        let e = RunConfig::from_toml_str(&format!("{MIN}[controller]\nm_bar = -1.0\n"), None)
            .unwrap_err();
        assert_eq!(
            e.to_string(),
            "config key `controller.m_bar` = -1 is out of range: 0 < m_bar <= 100 kg m^2"
        );
        let e =
            RunConfig::from_toml_str(&format!("{MIN}[controller]\ntde_delay_samples = 0\n"), None)
                .unwrap_err();
        assert!(
            e.to_string().contains("controller.tde_delay_samples` = 0"),
            "{e}"
        );
        let e = RunConfig::from_toml_str(&format!("{MIN}[loop]\nts_s = nan\n"), None).unwrap_err();
        assert!(e.to_string().contains("loop.ts_s` = NaN"), "{e}");
    }

    #[test]
    fn layouts_default_per_mode_and_validate() {
        let c = RunConfig::from_toml_str(&format!("{MIN}[loop.lockstep]\nspin_us = 5\n"), None)
            .unwrap();
        assert_eq!(c.loop_.realtime, Layout::realtime_default());
        assert_eq!(c.loop_.lockstep.spin_us, Some(5));
        assert_eq!(
            c.loop_.lockstep.plant_cpu,
            Layout::lockstep_default().plant_cpu
        );
        let e = RunConfig::from_toml_str(
            &format!("{MIN}[loop.realtime]\nplant_priority = 120\n"),
            None,
        )
        .unwrap_err();
        assert!(
            e.to_string()
                .contains("`loop.realtime.plant_priority` = 120"),
            "{e}"
        );
        let e = RunConfig::from_toml_str(&format!("{MIN}[loop]\ntorque_budget_us = 300\n"), None)
            .unwrap_err();
        assert!(
            e.to_string().contains("torque_budget_us` = 300")
                && e.to_string().contains("< Ts = 300"),
            "{e}"
        );
    }

    #[test]
    fn wake_early_us_is_bounded_by_the_period() {
        // Ts = 300 µs by default: a whole period early is allowed, more is not.
        for section in ["loop.realtime", "loop.lockstep"] {
            let c =
                RunConfig::from_toml_str(&format!("{MIN}[{section}]\nwake_early_us = 300\n"), None)
                    .unwrap();
            let layout = if section == "loop.realtime" {
                &c.loop_.realtime
            } else {
                &c.loop_.lockstep
            };
            assert_eq!(layout.wake_early_us, Some(300), "{section}");
            let e =
                RunConfig::from_toml_str(&format!("{MIN}[{section}]\nwake_early_us = 301\n"), None)
                    .unwrap_err();
            assert_eq!(
                e.to_string(),
                format!(
                    "config key `{section}.wake_early_us` = 301 is out of range: 0 <= wake_early_us <= Ts = 300 us"
                )
            );
        }
        // The bound follows the period.
        let e = RunConfig::from_toml_str(
            &format!("{MIN}[loop]\nts_s = 1e-3\ntorque_budget_us = 500\n[loop.realtime]\nwake_early_us = 1001\n"),
            None,
        )
        .unwrap_err();
        assert!(e.to_string().contains("<= Ts = 1000 us"), "{e}");
    }

    #[test]
    fn default_wake_early_us_fits_a_short_period() {
        // The realtime default (80 µs) is capped at a shorter period instead of rejected.
        let c = RunConfig::from_toml_str(
            &format!("{MIN}[loop]\nts_s = 5e-5\ntorque_budget_us = 20\n"),
            None,
        )
        .unwrap();
        assert_eq!(c.loop_.realtime.wake_early_us, Some(50));
        assert_eq!(c.loop_.realtime.controller_wake_early_us, Some(50));
        assert_eq!(c.loop_.lockstep.wake_early_us, Some(0));
        let again = RunConfig::from_toml_str(&c.to_toml_string(), None).unwrap();
        assert_eq!(c, again);
    }

    #[test]
    fn controller_wake_early_us_is_minus_one_or_within_the_period() {
        for (v, ok) in [
            ("-1", true),
            ("0", true),
            ("300", true),
            ("301", false),
            ("-2", false),
        ] {
            let r = RunConfig::from_toml_str(
                &format!("{MIN}[loop.realtime]\ncontroller_wake_early_us = {v}\n"),
                None,
            );
            match (r, ok) {
                (Ok(c), true) => assert_eq!(
                    c.loop_.realtime.controller_lead_ns(),
                    v.parse::<u64>().ok().map(|us| us * 1000)
                ),
                (Err(e), false) => assert_eq!(
                    e.to_string(),
                    format!(
                        "config key `loop.realtime.controller_wake_early_us` = {v} is out of range: -1 (wait for the notification) or 0 <= controller_wake_early_us <= Ts = 300 us"
                    )
                ),
                (r, _) => panic!("{v}: {r:?}"),
            }
        }
    }

    #[test]
    fn transport_delay_has_its_own_bound() {
        let ok = format!("{MIN}[plant]\ntransport_delay_samples = {MAX_TRANSPORT_DELAY}\n");
        assert!(RunConfig::from_toml_str(&ok, None).is_ok());
        let e = RunConfig::from_toml_str(
            &format!(
                "{MIN}[plant]\ntransport_delay_samples = {}\n",
                MAX_TRANSPORT_DELAY + 1
            ),
            None,
        )
        .unwrap_err();
        assert_eq!(
            e.to_string(),
            "config key `plant.transport_delay_samples` = 10001 is out of range: 0 <= transport_delay_samples <= 10000 ticks"
        );
        let e = RunConfig::from_toml_str(
            &format!(
                "{MIN}[controller]\ntde_delay_samples = {}\n",
                MAX_TDE_DELAY + 1
            ),
            None,
        )
        .unwrap_err();
        assert_eq!(
            e.to_string(),
            "config key `controller.tde_delay_samples` = 10001 is out of range: 1 <= tde_delay_samples <= 10000 ticks"
        );
    }

    #[test]
    fn payload_step_tick_matches_spec() {
        for (path, k) in [("s1", 1334), ("s2", 334), ("s3", 2000)] {
            let c = RunConfig::from_toml_str(
                &format!("[scenario]\npath = \"{path}\"\n[plant]\npayload_step_kg = 0.5\n"),
                None,
            )
            .unwrap();
            assert_eq!(c.payload_step_tick(), Some(k), "{path}");
        }
        assert_eq!(
            RunConfig::from_toml_str(MIN, None)
                .unwrap()
                .payload_step_tick(),
            None
        );
    }

    #[test]
    fn unknown_law_lists_allowed() {
        let e = RunConfig::from_toml_str(&format!("{MIN}[controller]\nlaws = [\"lqr\"]\n"), None)
            .unwrap_err();
        let msg = e.to_string();
        assert!(msg.contains("lqr") && msg.contains("tdc-is-sta"), "{msg}");
    }

    /// One line, naming the key; for the assertions below.
    fn err(text: &str) -> String {
        let e = RunConfig::from_toml_str(text, Some(Path::new("configs/t.toml")))
            .unwrap_err()
            .to_string();
        assert!(!e.contains('\n') && !e.contains('\r'), "not one line: {e}");
        e
    }

    #[test]
    fn regression_name_escapes_the_run_folder() {
        for bad in [
            "../../../../tmp/victim",
            "a/b",
            "x\ny",
            "\u{202e}fdp.exe",
            "\u{200f}abc",
            ".hidden",
            "-rf",
            "..",
            "tab\there",
            "é",
        ] {
            let e = err(&format!("name = {}\n{MIN}", toml::Value::from(bad)));
            let shown = show_str(bad);
            assert_eq!(
                e,
                format!("config key `name` = {shown} is out of range: {NAME_RULE}"),
                "{bad:?}"
            );
        }
        // Control and format characters are visible, not acted upon.
        assert!(err(&format!("name = \"x\\ny\"\n{MIN}")).contains(r#""x\ny""#));
        assert!(err(&format!("name = \"\\u202eab\"\n{MIN}")).contains(r#""\u{202e}ab""#));
        // A long name is cut in the message.
        let e = err(&format!("name = \"{}\"\n{MIN}", "a".repeat(65)));
        assert!(e.contains(&format!("\"{}…\"", "a".repeat(60))), "{e}");
        for good in ["s2-fast", "A.b_c-1", "x", &"a".repeat(64)] {
            let c = RunConfig::from_toml_str(&format!("name = {good:?}\n{MIN}"), None).unwrap();
            assert_eq!(c.name, good);
        }
        // The default (the file stem) is made valid rather than rejected.
        for (stem, name) in [
            ("my scenario\n", "my_scenario_"),
            (".x", "_x"),
            ("-x", "_x"),
            ("s1", "s1"),
        ] {
            let p = PathBuf::from(format!("/tmp/{stem}.toml"));
            let c = RunConfig::from_toml_str(MIN, Some(&p)).unwrap();
            assert_eq!(c.name, name, "{stem:?}");
        }
    }

    #[test]
    fn regression_parse_error_is_one_line_with_line_and_column() {
        let e = err(&format!("{MIN}[plant]\nfrictoin = true\n"));
        assert!(
            e.starts_with(
                "invalid config configs/t.toml: unknown field `frictoin`, expected one of"
            ) && e.ends_with(" at line 4, column 1"),
            "{e}"
        );
        let e = err("[scenario]\npath = \"s1\"\nhold_s = = 2\n");
        assert!(e.ends_with("at line 3, column 10"), "{e}");
        assert!(!e.contains('|') && !e.contains('^'), "no snippet: {e}");
        // Columns count characters, not bytes.
        let e = err("description = \"ℓℓ\" x\n[scenario]\npath = \"s1\"\n");
        assert!(e.ends_with("at line 1, column 20"), "{e}");
        // A value echoed by the parser has its control characters escaped.
        let e = err("[scenario]\npath = \"s9\\nfoo\\u200f\"\n");
        assert!(e.contains(r"`s9\nfoo\u{200f}`"), "{e}");
    }

    #[test]
    fn regression_huge_values_are_echoed_compactly() {
        let e = err(&format!("{MIN}[controller]\nm_bar = 1e308\n"));
        assert_eq!(
            e,
            "config key `controller.m_bar` = 1e308 is out of range: 0 < m_bar <= 100 kg m^2"
        );
        let e = err(&format!("{MIN}[controller]\nkp = -1.5e-300\n"));
        assert!(e.contains("`controller.kp` = -1.5e-300 is"), "{e}");
        let e = err(&format!("{MIN}[controller]\nkp = 123456.5e10\n"));
        assert!(e.contains("= 1.234565e15 is"), "{e}");
        // Plain numbers stay plain.
        let e = err(&format!("{MIN}[controller]\nkp = -2.5\n"));
        assert!(e.contains("= -2.5 is"), "{e}");
        // A 200 KB string is cut, whatever echoes it.
        let long = "x".repeat(200_000);
        for text in [
            format!("[scenario]\npath = \"{long}\"\n"),
            format!("{MIN}[faults]\ninject = \"{long}\"\n"),
            format!("{MIN}[plant]\nsubsteps = \"{long}\"\n"),
            format!("{MIN}{long} = 1\n"),
            format!("name = \"{long}\"\n{MIN}"),
        ] {
            let e = err(&text);
            assert!(
                e.len() < 600 && e.contains('…'),
                "{} chars: {}",
                e.len(),
                &e[..200]
            );
        }
    }

    #[test]
    fn regression_run_shorter_than_one_period() {
        let seg = |d: &str| {
            format!(
                "[scenario]\npath = \"custom\"\nsegments = [{{ from = [0.25, 0, -0.43], to = [-0.25, 0, -0.43], apex_m = 0.12, duration_s = {d} }}]\n"
            )
        };
        assert_eq!(
            err(&seg("1e-300")),
            "config key `scenario.segments[0].duration_s` = 1e-300 is out of range: Ts = 0.0003 s <= duration_s <= 3600 s (a segment lasts at least one control period)"
        );
        assert!(err(&seg("2.9e-4")).contains("= 0.00029 is out of range"));
        let c = RunConfig::from_toml_str(&seg("3e-4"), None).unwrap();
        assert_eq!(c.ticks(c.motion_duration_s()), 1);
    }

    #[test]
    fn regression_payload_step_after_the_run() {
        let at = |t: &str| {
            format!(
                "[scenario]\npath = \"s1\"\nhold_s = 0.1\n[plant]\npayload_step_kg = 0.5\npayload_step_at_s = {t}\n"
            )
        };
        // S1: T = 0.8 s, hold 0.1 s, N = 3000 ticks: the last interval starts at 2999·Ts.
        assert_eq!(
            err(&at("5.0")),
            "config key `plant.payload_step_at_s` = 5 is out of range: 0 <= payload_step_at_s <= 0.8997 s, the start of the last control period (motion + hold = 0.9 s)"
        );
        assert!(err(&at("0.9")).contains("payload_step_at_s` = 0.9 is"));
        let c = RunConfig::from_toml_str(&at("0.8997"), None).unwrap();
        assert_eq!(c.payload_step_tick(), Some(2999));
        // Even without a mass, a step time outside the run is not silently ignored.
        let e = err("[scenario]\npath = \"s2\"\n[plant]\npayload_step_at_s = 1.0\n");
        assert!(e.contains("plant.payload_step_at_s` = 1 is"), "{e}");
    }

    #[test]
    fn regression_rk4_step_below_one_microsecond() {
        assert_eq!(
            err(&format!(
                "{MIN}[loop]\nts_s = 1e-5\ntorque_budget_us = 5\n[plant]\nsubsteps = 1000\n"
            )),
            "config key `plant.substeps` = 1000 is out of range: 1 <= substeps <= 10 for ts_s = 1e-5 s (the RK4 step ts_s/substeps must be >= 1 us)"
        );
        assert!(RunConfig::from_toml_str(&format!("{MIN}[plant]\nsubsteps = 300\n"), None).is_ok());
        assert!(
            err(&format!("{MIN}[plant]\nsubsteps = 301\n")).contains("<= 300 for ts_s = 0.0003 s")
        );
        // The default (10) fits the shortest period.
        assert!(
            RunConfig::from_toml_str(
                &format!("{MIN}[loop]\nts_s = 1e-5\ntorque_budget_us = 5\n"),
                None
            )
            .is_ok()
        );
    }

    #[test]
    fn regression_config_file_must_be_a_small_regular_file() {
        let dir = std::env::temp_dir().join(format!("deltaloop-cfg-read-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let read = |p: &Path| RunConfig::from_file(p).unwrap_err().to_string();
        let e = read(&dir);
        assert!(
            e.contains(&dir.display().to_string())
                && e.contains("it is a directory, not a regular file"),
            "{e}"
        );
        let e = read(Path::new("/dev/zero"));
        assert_eq!(
            e,
            "cannot read config file /dev/zero: it is a character device, not a regular file"
        );
        let fifo = dir.join("fifo.toml");
        if std::process::Command::new("mkfifo")
            .arg(&fifo)
            .status()
            .is_ok_and(|s| s.success())
        {
            let e = read(&fifo);
            assert!(
                e.contains("it is a FIFO (named pipe), not a regular file"),
                "{e}"
            );
        }
        let big = dir.join("big.toml");
        let mut text = MIN.to_string();
        text.push_str(&"#".repeat(MAX_FILE_BYTES as usize));
        std::fs::write(&big, &text).unwrap();
        let e = read(&big);
        assert!(e.contains("larger than 1 MiB"), "{e}");
        std::fs::write(&big, &text[..MAX_FILE_BYTES as usize]).unwrap();
        assert!(RunConfig::from_file(&big).is_ok());
        std::fs::write(&big, b"[scenario]\npath = \"s1\"\n#\xff\n").unwrap();
        assert!(read(&big).contains("not UTF-8"));
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn missing_file_is_named() {
        let e = RunConfig::from_file(Path::new("/nonexistent/cfg.toml")).unwrap_err();
        assert!(e.to_string().contains("/nonexistent/cfg.toml"), "{e}");
    }
}
