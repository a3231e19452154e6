//! The scenario file: the serde structs of its sections, their defaults, and reading and writing
//! a [`RunConfig`] (parse, fill the preset and the layouts, validate).

use crate::error::ConfigError;
use crate::files::read_text_file;
use crate::layout::Layout;
use crate::text::{clean_message, show_path, toml_error_position};
use deltaloop_names::{ControllerParams, Law, Preset, VelocitySource};
use serde::{Deserialize, Serialize};
use std::path::Path;

deltaloop_names::text_enum! {
    "kebab-case", "path";
    /// Which reference path to follow (docs/delta-robot.md §6).
    #[derive(PartialOrd, Ord)]
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

deltaloop_names::text_enum! {
    "kebab-case", "overrun policy";
    /// What the realtime plant does when its own process wakes for a tick later than the bound
    /// (`[loop] overrun`, `--overrun`): the host stalled the simulator, not the robot.
    #[derive(Default)]
    pub enum Overrun {
        /// Simulated time pauses for the stall: the plant's clock epoch moves by its lateness, the
        /// backlog is not integrated, and the run's real-time factor falls below 1 (and says so).
        #[default]
        Stretch,
        /// The plant stays locked to the wall clock: it runs the missed ticks back to back, each
        /// reply acting at its (late) arrival, as a real robot would have moved meanwhile.
        CatchUp,
        /// The plant stops the loop with an overrun fault and brakes, as a realtime target does on
        /// a task overrun.
        Fault,
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

macro_rules! controller_section {
    ($($(#[$doc:meta])* $name:ident,)*) => {
        /// `[controller]`: laws, preset, TDE delay, and per-key overrides of the preset's constants
        /// (None: the preset's value; every gain of [`ControllerParams`], with its unit there).
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

            /// What the run calls the controller that ran (the tables, `summary.json`,
            /// `report.md`), beside the law it answered as. Empty: the file name of `command`'s
            /// program (its script's, for an interpreter), or none for the built-in controller.
            #[serde(default, skip_serializing_if = "String::is_empty")]
            pub label: String,

            $($(#[$doc])* pub $name: Option<f64>,)*
        }

        impl ControllerSection {
            /// The constants: the preset with this section's overrides applied.
            pub fn params(&self) -> ControllerParams {
                let p = ControllerParams::preset(self.preset);
                ControllerParams {
                    $($name: self.$name.unwrap_or(p.$name),)*
                }
            }

            /// Writes the constants into every override that is not set: the config is explicit.
            fn resolve_preset(&mut self) {
                let p = self.params();
                $(self.$name = Some(p.$name);)*
            }
        }
    };
}

deltaloop_names::with_controller_gains!(controller_section);

fn default_laws() -> Vec<Law> {
    Law::STUDY.to_vec()
}
fn default_ell() -> u32 {
    1
}

impl Default for ControllerSection {
    fn default() -> Self {
        toml::from_str("").expect("empty controller section")
    }
}

impl ControllerSection {
    /// What a run calls a controller started with `command` (program, then arguments): the file
    /// name of its program, or of its script for an interpreter (`python3 x.py` is `x.py`);
    /// `env [-…] [K=V…] prog …` is `prog`'s. None for no command (the built-in controller).
    pub fn command_label(command: &[String]) -> Option<String> {
        // One line, bounded: a command's words are only checked for NUL.
        let base = |w: &str| w.rsplit('/').next().unwrap_or(w).to_string();
        let file = |w: &str| show_path(Path::new(&base(w)));
        // `env [-…] [K=V…] prog …` runs `prog`.
        let words: Vec<&str> = command.iter().map(String::as_str).collect();
        let words = match words.split_first() {
            Some((env, rest)) if base(env) == "env" => {
                let at = rest
                    .iter()
                    .position(|w| !w.starts_with('-') && !w.contains('='))
                    .unwrap_or(rest.len());
                &rest[at..]
            }
            _ => &words[..],
        };
        let (program, args) = words.split_first()?;
        let script = args.iter().find(|w| !w.starts_with('-'));
        Some(match script {
            Some(s) if is_interpreter(&base(program)) => file(s),
            _ => file(program),
        })
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

    /// Realtime: what the plant does when its own process wakes for a tick more than
    /// `overrun_after_us` late (the host did not run it): pause simulated time (`stretch`), run
    /// the backlog on the wall clock (`catch-up`), or end the run (`fault`). A late reply from
    /// the controller or the link never triggers it: that latency acts on the physics.
    #[serde(default)]
    pub overrun: Overrun,

    /// Realtime: the plant's wake lateness beyond which `overrun` acts, µs (1..=1000000).
    /// Default: one period Ts (a later wake would push every reply past its tick).
    #[serde(default)]
    pub overrun_after_us: Option<u32>,
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
            overrun: Overrun::default(),
            overrun_after_us: None,
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
    /// One process of the run on another host (None: every process on this one).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub link: Option<LinkSection>,
    /// ROS 2: the run's live topics (`--ros2`) and a ROS 2 node as the controller
    /// (`--controller ros2`). None: the defaults, when either asks.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ros2: Option<Ros2Section>,
}

/// `[ros2]`: how deltaloop appears in a ROS 2 graph (docs/guide/ros2.md). DDS without
/// DDS-Security authenticates no one, so discovery stays on this host unless asked otherwise.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Ros2Section {
    /// DDS domain, 0..=232 (None: `ROS_DOMAIN_ID`, else 0).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub domain: Option<u16>,
    /// Discovery range (None: `ROS_AUTOMATIC_DISCOVERY_RANGE`, else `localhost`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub range: Option<Ros2Range>,
    /// The live topics' namespace: `/<namespace>/<law>/joint_states`, … (ROS name tokens).
    pub namespace: String,
    /// Publish every this many ticks (1: every tick; 10: 333 Hz at Ts = 0.3 ms).
    pub every: u32,
    /// `--controller ros2`: the robot's joint states, published by deltaloop (a ROS name).
    pub state_topic: String,
    /// `--controller ros2`: the node's commands (JointState, `effort` in N m) (a ROS name).
    pub command_topic: String,
    /// The ROS 2 distribution whose graph format `ros_discovery_info` uses.
    pub distro: Ros2Distro,
    /// `--controller ros2`: how long to wait for the node to appear, s.
    pub wait_s: f64,
}

impl Default for Ros2Section {
    fn default() -> Self {
        Self {
            domain: None,
            range: None,
            namespace: "deltaloop".into(),
            every: 10,
            state_topic: "/robot_joint_states".into(),
            command_topic: "/robot_joint_commands".into(),
            distro: Ros2Distro::default(),
            wait_s: 20.0,
        }
    }
}

deltaloop_names::text_enum! {
    "lowercase", "ROS 2 discovery range";
    /// How far DDS discovery reaches (`[ros2] range`, ROS 2's `ROS_AUTOMATIC_DISCOVERY_RANGE`).
    pub enum Ros2Range {
        /// This host only (loopback): the default.
        Localhost,
        /// The local networks (multicast): anyone there can read the run and, with
        /// `--controller ros2`, command the robot.
        Subnet,
    }
}

deltaloop_names::text_enum! {
    "lowercase", "ROS 2 distribution";
    /// The graph format of `ros_discovery_info`: Humble's 24-byte gids or Jazzy's 16.
    #[derive(Default)]
    pub enum Ros2Distro {
        Humble,
        #[default]
        Jazzy,
    }
}

/// `[link]`: one process of the run on another host, across `deltaloop-bridge`
/// (docs/guide/two-hosts.md). `deltaloop run --controller-remote/--plant-remote` and a sweep's
/// `link_delay_us` axis write it into the run's config; the near bridge, the report and the
/// supervisor read it from there. The emulated delay, jitter and loss act on each datagram, each
/// direction.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LinkSection {
    /// Which process runs on the other host.
    pub remote: RemoteSide,
    /// Where this host listens for the far side (TCP and UDP, one port): `IP:PORT`.
    pub listen: String,
    /// Emulated one-way delay, µs.
    #[serde(default)]
    pub delay_us: f64,
    /// Emulated one-way jitter, µs: uniform in [0, this] on top of the delay.
    #[serde(default)]
    pub jitter_us: f64,
    /// Emulated loss: the fraction of datagrams dropped, 0..=1.
    #[serde(default)]
    pub loss: f64,
    /// Seed of the emulated jitter and loss (the far side draws with seed + 1).
    #[serde(default = "default_link_seed")]
    pub seed: u64,
    /// How long the near bridge polls for a reply after sending a state before it blocks, µs
    /// (the relay path's).
    #[serde(default)]
    pub spin_us: u32,
    /// How the loop's messages cross: `direct` (plant and controller socket to socket, each
    /// bridge handing its socket to the loop process beside it) or `relay` (through both
    /// bridges, as a process that speaks only iceoryx2 always is).
    #[serde(default, skip_serializing_if = "LinkPath::is_direct")]
    pub path: LinkPath,
}

deltaloop_names::text_enum! {
    "lowercase", "link path";
    /// How the loop's messages cross the link (`[link] path`, `--link-path`).
    #[derive(Default)]
    pub enum LinkPath {
        /// Socket to socket between the loop processes (a process that cannot take the socket is
        /// relayed by its bridge).
        #[default]
        Direct,
        /// Through both bridges.
        Relay,
    }
}

impl LinkPath {
    pub fn is_direct(&self) -> bool {
        *self == LinkPath::Direct
    }
}

fn default_link_seed() -> u64 {
    1
}

deltaloop_names::text_enum! {
    "lowercase", "remote side";
    /// The process of a run that is on the other host: `[link] remote`, `join --role`, the
    /// `--controller-remote`/`--plant-remote` flags, and the side a bridge stands in for.
    pub enum RemoteSide {
        /// The controller there; the plant and the supervisor here.
        Controller,
        /// The plant there; the controller and the supervisor here.
        Plant,
    }
}

/// The emulated network of a link, each direction on each side's sends (this kernel has no
/// `netem`): `[link]`'s `delay_us`, `jitter_us`, `loss` and `seed`, and `run`'s `--link-*` flags.
/// Checked by [`LinkEmulation::check`], the one place of its bounds.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LinkEmulation {
    /// One-way delay, µs.
    pub delay_us: f64,
    /// One-way jitter, µs: uniform in [0, this] on top of the delay.
    pub jitter_us: f64,
    /// The fraction of datagrams dropped, 0..=1.
    pub loss: f64,
    /// Seed of the jitter and loss draws (the far side draws with seed + 1).
    pub seed: u64,
}

impl Default for LinkEmulation {
    fn default() -> Self {
        Self {
            delay_us: 0.0,
            jitter_us: 0.0,
            loss: 0.0,
            seed: default_link_seed(),
        }
    }
}

impl LinkEmulation {
    /// Whether it emulates nothing (no delay, jitter or loss).
    pub fn is_off(&self) -> bool {
        self.delay_us == 0.0 && self.jitter_us == 0.0 && self.loss == 0.0
    }
}

impl LinkSection {
    /// Whether any emulation (delay, jitter or loss) is on.
    pub fn emulated(&self) -> bool {
        !self.emulation().is_off()
    }

    /// Its emulated network.
    pub fn emulation(&self) -> LinkEmulation {
        LinkEmulation {
            delay_us: self.delay_us,
            jitter_us: self.jitter_us,
            loss: self.loss,
            seed: self.seed,
        }
    }
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
/// The default name from a file stem: every character outside [`NAME_RULE`](crate::validate::NAME_RULE) becomes `_`, a
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
        cfg.controller.resolve_preset();
        let ts = cfg.loop_.ts_s;
        cfg.loop_.realtime.fill(Layout::realtime_default(), ts);
        cfg.loop_.lockstep.fill(Layout::lockstep_default(), ts);
        if cfg.loop_.overrun_after_us.is_none() && ts.is_finite() && ts > 0.0 {
            cfg.loop_.overrun_after_us = Some((ts * 1e6).round().clamp(1.0, 1e6) as u32);
        }
        cfg.validate()?;
        Ok(cfg)
    }

    /// Reads and parses a file: a regular file of at most [`crate::MAX_FILE_BYTES`] (see
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

    /// What the run calls its controller (see [`ControllerSection::label`]): the label, or the
    /// file name of the command's program (of its script, for an interpreter: `python3 x.py` is
    /// `x.py`); None for the built-in controller. With the controller on another host
    /// (`[link] remote = "controller"`) the command is the near bridge that stands in for it,
    /// not the controller: only the label counts (the far side names a controller of the
    /// user's in its READY).
    pub fn controller_label(&self) -> Option<String> {
        let c = &self.controller;
        if !c.label.is_empty() {
            return Some(c.label.clone());
        }
        if self
            .link
            .as_ref()
            .is_some_and(|l| l.remote == RemoteSide::Controller)
        {
            return None;
        }
        ControllerSection::command_label(&c.command)
    }

    /// The plant's wake lateness beyond which the overrun policy acts, ns (see
    /// [`LoopSection::overrun_after_us`]; one period if unset).
    pub fn overrun_after_ns(&self) -> u64 {
        self.loop_
            .overrun_after_us
            .map_or_else(|| self.ts_ns(), |us| u64::from(us) * 1000)
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
pub(crate) fn step_tick(t: f64, ts: f64) -> u64 {
    let k = (t / ts).ceil();
    // Guard against round-off pushing an exact multiple one tick up.
    if ((k - 1.0) * ts - t).abs() < 1e-12 * t.max(1.0) {
        (k - 1.0) as u64
    } else {
        k as u64
    }
}

/// Whether a program's file name is a script interpreter, whose first non-option argument
/// names what runs: `python3`, `python3.11`, `sh`, `bash`, `node`, `ruby`, `perl`, exactly.
fn is_interpreter(name: &str) -> bool {
    let versioned = |stem: &str| {
        name.strip_prefix(stem)
            .is_some_and(|v| v.chars().all(|c| c.is_ascii_digit() || c == '.'))
    };
    ["sh", "bash", "dash", "zsh", "node", "ruby", "perl"].contains(&name)
        || versioned("python")
        || versioned("pypy")
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::files::MAX_FILE_BYTES;
    use crate::test_util::{MIN, err};

    /// Regression: the label was guessed by prefix (`shaper` and `envoy-ctl` taken for the
    /// interpreters `sh` and `env`), and `env K=V prog` was labelled `K=V`.
    #[test]
    fn regression_a_controller_label_is_its_program_or_script() {
        let label = |cmd: &[&str]| {
            let mut c = RunConfig::from_toml_str(MIN, None).unwrap();
            c.controller.command = cmd.iter().map(|w| w.to_string()).collect();
            c.controller_label()
        };
        let some = |s: &str| Some(s.to_string());
        assert_eq!(label(&[]), None);
        assert_eq!(label(&["/opt/x/c-tdc", "--fast"]), some("c-tdc"));
        assert_eq!(label(&["python3", "-u", "ctl/law.py", "a"]), some("law.py"));
        assert_eq!(label(&["/usr/bin/python3.11", "law.py"]), some("law.py"));
        assert_eq!(label(&["shaper", "cfg.toml"]), some("shaper"));
        assert_eq!(label(&["envoy-ctl", "x"]), some("envoy-ctl"));
        assert_eq!(label(&["perlin-ctrl", "x"]), some("perlin-ctrl"));
        assert_eq!(label(&["env", "FOO=1", "-i", "ctrl", "a"]), some("ctrl"));
        assert_eq!(label(&["env", "python3", "law.py"]), some("law.py"));
        assert_eq!(label(&["sh", "-c", "run.sh"]), some("run.sh"));
    }

    /// Regression: with the controller on another host the run's controller command is the
    /// near bridge, and a built-in far controller was labelled `deltaloop-bridge` as a foreign
    /// one. The near bridge is nobody's label; an explicit label still is.
    #[test]
    fn regression_a_remote_controller_is_not_labelled_after_the_near_bridge() {
        let mut c = RunConfig::from_toml_str(
            &format!(
                "{MIN}[link]
remote = \"controller\"
listen = \"127.0.0.1:7447\"
"
            ),
            None,
        )
        .unwrap();
        c.controller.command = vec!["/opt/dl/deltaloop-bridge".into(), "near".into()];
        assert_eq!(c.controller_label(), None);
        c.controller.label = "rig".into();
        assert_eq!(c.controller_label(), Some("rig".into()));
    }

    #[test]
    fn minimal_file_gets_matched_preset_and_all_laws() {
        let c = RunConfig::from_toml_str(MIN, Some(Path::new("configs/x.toml"))).unwrap();
        assert_eq!(c.name, "x");
        assert_eq!(c.controller.laws, Law::STUDY.to_vec());
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
