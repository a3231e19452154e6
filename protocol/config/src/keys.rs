//! Every key of a scenario file, declared once: its TOML path, type, unit, allowed values,
//! default and doc line. From here come the serde defaults of the sections (`#[serde(default =
//! "PlantKeys::tau_max_nm")]`), the range checks and their one-line errors (`PLANT.tau_max_nm
//! .check(v)`), the key table of docs/guide/scenario-files.md and the config fuzzer's keys. Its
//! tests (`keys/tests.rs`) fail when the serde schema has a key it does not declare (or lacks
//! one it does), a default, a range check or the doc table disagrees with it.
//!
//! A new key: its line here, its field in its section (the section's file in `sections/`, whose
//! `validate` calls the key's check), and `DELTALOOP_UPDATE_DOCS=1 cargo test -p
//! deltaloop-config keys` writes its row of the doc table. The controller's gains are declared by
//! `with_controller_gains!` (crate `deltaloop-names`); their keys follow from it ([`gain_keys`]).

use crate::key::{Allowed, Key, KeyDefault};
use crate::limits::{
    COMMAND_RULE, LABEL_RULE, MAX_HOLD_S, MAX_LINK_DELAY_US, MAX_SUBSTEPS, MAX_TDE_DELAY,
    MAX_TRANSPORT_DELAY, MAX_TRANSPORT_DELAY_US, NAME_RULE, ROS_NAME_RULE,
};
use crate::sections::{
    ApplyTorque, FaultInjection, LinkPath, Overrun, Ros2Distro, Segment, TorqueLimit,
};
use deltaloop_names::{Compensation, DelaySource, Law, Preset, VelocitySource};

/// Declares each table's keys: a struct with one [`Key`] per field, its one `static`, and per
/// key with a value default (`= (value)`) the function serde's `default` names. A default in
/// words (`= "…"`) is worked out when the file is read; `= per_mode` is the layout's.
macro_rules! declare_keys {
    (@default $Keys:ident $field:ident ($value:expr)) => {
        KeyDefault::Value(|| toml::Value::try_from($Keys::$field()).expect("a default serialises"))
    };
    (@default $Keys:ident $field:ident per_mode) => {
        KeyDefault::PerMode
    };
    (@default $Keys:ident $field:ident $said:literal) => {
        KeyDefault::Said($said)
    };
    (@default_fn $field:ident $ty:ty, ($value:expr)) => {
        #[doc = concat!("The default of `", stringify!($field), "`.")]
        pub fn $field() -> $ty {
            $value
        }
    };
    (@default_fn $field:ident $ty:ty, $other:tt) => {};
    ($(
        $(#[doc = $tdoc:literal])*
        $konst:ident: $Keys:ident = $table:literal {
            $(
                #[doc = $doc:literal]
                $field:ident: $ty:ty = $default:tt, $unit:literal, $allowed:expr;
            )*
        }
    )*) => {
        $(
            $(#[doc = $tdoc])*
            #[derive(Clone, Copy, Debug)]
            pub struct $Keys {
                $(#[doc = $doc] pub $field: Key,)*
            }

            $(#[doc = $tdoc])*
            pub static $konst: $Keys = $Keys {
                $($field: Key {
                    table: $table,
                    field: stringify!($field),
                    ty: stringify!($ty),
                    unit: $unit,
                    allowed: $allowed,
                    default: declare_keys!(@default $Keys $field $default),
                    doc: $doc,
                },)*
            };

            impl $Keys {
                $(declare_keys!(@default_fn $field $ty, $default);)*

                /// Its keys, in the order of the file's section.
                pub fn keys(&self) -> Vec<Key> {
                    vec![$(self.$field),*]
                }
            }
        )*
    };
}

const LINK_DELAY_WORDS: &str = "0 <= value <= 1000000 us";

declare_keys! {
    /// The keys outside every table.
    ROOT: RootKeys = "" {
        /// Scenario name: the run folder and the reports use it.
        name: String = "the file's stem, made valid", "", Allowed::Rule(NAME_RULE);
        /// Free text for reports.
        description: String = (String::new()), "", Allowed::Any;
    }

    /// `[scenario]`: the reference motion.
    SCENARIO: ScenarioKeys = "scenario" {
        /// The reference path (docs/delta-robot.md §6).
        path: PathKind = "required", "", Allowed::Words("s1 | s2 | s3 | custom");
        /// The semi-ellipses of a custom path: `from`, `to` (m, base frame, within ±2 m), `apex_m` (m, ±1), `duration_s` (s, Ts..=3600).
        segments: Vec<Segment> = (Vec::new()), "", Allowed::Rule("at least one with path = \"custom\", none otherwise");
        /// Extra time after the motion, holding its end point (the run's ticks are bounded too).
        hold_s: f64 = (0.0), "s", Allowed::closed(0.0, MAX_HOLD_S).note("(24 h)");
    }

    /// `[plant]`: the simulated robot.
    PLANT: PlantKeys = "plant" {
        /// Joint friction d_f = Fv q̇ + Fc tanh(q̇/ε), unknown to the controller.
        friction: bool = (false), "", Allowed::Any;
        /// Drive torque limit per joint.
        tau_max_nm: f64 = (100.0), "N m", Allowed::left_open(0.0, 1e4);
        /// RK4 steps per control period; the step Ts/substeps is at least 1 µs.
        substeps: u32 = (10), "", Allowed::closed(1.0, MAX_SUBSTEPS as f64);
        /// Transport delay in whole ticks d: τ_k acts over [t_{k+d}, t_{k+d+1}).
        transport_delay_samples: u32 = (0), "ticks", Allowed::closed(0.0, MAX_TRANSPORT_DELAY as f64);
        /// Transport delay beyond the whole ticks: D = d·Ts + this.
        transport_delay_us: f64 = (0.0), "µs", Allowed::closed(0.0, MAX_TRANSPORT_DELAY_US);
        /// Your own plant process, program then arguments (docs/guide/own-process.md); empty: the built-in one.
        command: Vec<String> = (Vec::new()), "", Allowed::Rule(COMMAND_RULE);
        /// Realtime: a reply acts at its measured arrival or at its tick (plus D).
        apply_torque: ApplyTorque = (ApplyTorque::Arrival), "", Allowed::Words("arrival | tick");
        /// Payload mass after the step (0: no step).
        payload_step_kg: f64 = (0.0), "kg", Allowed::closed(0.0, 10.0).note("(0: no step)");
        /// When the payload step happens (the first tick at or after it), within the run.
        payload_step_at_s: Option<f64> = "T/2", "s", Allowed::closed(0.0, 3600.0);
    }

    /// `[controller]`: the laws, the preset and the TDE delay (the gains: [`gain_keys`]).
    CONTROLLER: ControllerKeys = "controller" {
        /// The preset the constants start from (docs/controllers.md).
        preset: Preset = (Preset::default()), "", Allowed::Words("matched | paper");
        /// The laws to run, each one run of the scenario.
        laws: Vec<Law> = (Law::STUDY.to_vec()), "", Allowed::Rule("at least one law, each at most once");
        /// TDE delay ℓ (L = ℓ·Ts).
        tde_delay_samples: u32 = (1), "ticks", Allowed::closed(1.0, MAX_TDE_DELAY as f64);
        /// Delay compensation: the law acts on the state predicted for when its torque acts (docs/controllers.md).
        compensate: Compensation = (Compensation::None), "", Allowed::Words("none | predict");
        /// The delay D₀ a compensated law predicts over (with compensate = "predict" only; docs/guide/delay-study.md).
        compensate_delay_us: Option<f64> = "the transport delay", "µs", Allowed::closed(0.0, MAX_TRANSPORT_DELAY_US);
        /// D₀ as it is, or measured each tick from the drives' reports, D₀ to D₀ + Ts (with compensate = "predict" only; docs/controllers.md).
        compensate_delay: DelaySource = (DelaySource::Config), "", Allowed::Words("config | measured");
        /// Extra wall time per reply (realtime: real misses; inproc: no effect).
        compute_delay_us: u32 = (0), "us", Allowed::closed(0.0, 1e6);
        /// Your own controller process, program then arguments (docs/guide/own-process.md); empty: the built-in one.
        command: Vec<String> = (Vec::new()), "", Allowed::Rule(COMMAND_RULE);
        /// What the tables call the controller (empty: the command's program or script).
        label: String = (String::new()), "", Allowed::Rule(LABEL_RULE);
    }

    /// `[loop]`: the timing of the control loop.
    LOOP: LoopKeys = "loop" {
        /// Control period Ts.
        ts_s: f64 = (3e-4), "s", Allowed::closed(1e-5, 0.1);
        /// Realtime: how long after publishing a state the plant waits for its torque.
        torque_budget_us: u32 = (150), "us", Allowed::Rule("0 < torque_budget_us < Ts");
        /// A peer silent this long is a fault (lockstep, and the controller's wait for states).
        silence_timeout_ms: u32 = (2000), "ms", Allowed::closed(10.0, 600_000.0);
        /// Realtime, the plant's own process woke too late: pause simulated time, run the backlog, or end the run.
        overrun: Overrun = (Overrun::Stretch), "", Allowed::Words("stretch | catch-up | fault");
        /// Realtime: the plant's wake lateness beyond which `overrun` acts.
        overrun_after_us: Option<u32> = "one period Ts", "us", Allowed::closed(1.0, 1e6);
    }

    /// `[loop.realtime]`, `[loop.lockstep]`: where and how the loop processes run in each mode
    /// (docs/guide/loop-modes.md, "Scheduling layouts").
    LAYOUT: LayoutKeys = "loop.<mode>" {
        /// CPU of the plant process (-1: not pinned).
        plant_cpu: Option<i32> = per_mode, "", Allowed::span(-1.0, 1023.0, "-1 (not pinned) or a CPU index 0..=1023");
        /// CPU of the controller process (-1: not pinned).
        controller_cpu: Option<i32> = per_mode, "", Allowed::span(-1.0, 1023.0, "-1 (not pinned) or a CPU index 0..=1023");
        /// CPU of the supervisor's collector (-1: not pinned).
        supervisor_cpu: Option<i32> = per_mode, "", Allowed::span(-1.0, 1023.0, "-1 (not pinned) or a CPU index 0..=1023");
        /// SCHED_FIFO priority of the plant (0: SCHED_OTHER).
        plant_priority: Option<i32> = per_mode, "", Allowed::span(0.0, 99.0, "0 (SCHED_OTHER) or a SCHED_FIFO priority 1..=99");
        /// SCHED_FIFO priority of the controller (0: SCHED_OTHER).
        controller_priority: Option<i32> = per_mode, "", Allowed::span(0.0, 99.0, "0 (SCHED_OTHER) or a SCHED_FIFO priority 1..=99");
        /// How long a process busy-polls for its peer's message before blocking.
        spin_us: Option<u32> = per_mode, "us", Allowed::closed(0.0, 1e6);
        /// mlockall in both loop processes.
        lock_memory: Option<bool> = per_mode, "", Allowed::Any;
        /// Realtime: the plant wakes this long before each deadline and busy-waits the rest.
        wake_early_us: Option<u32> = per_mode, "us", Allowed::Rule("0 <= wake_early_us <= Ts");
        /// Realtime: the controller wakes this long before each deadline and polls for the state (-1: woken by the plant).
        controller_wake_early_us: Option<i32> = per_mode, "us", Allowed::Rule("-1 (wait for the notification) or 0 <= controller_wake_early_us <= Ts");
        /// Between two looks for the peer's message: spin, or yield to a peer on the same CPU at the same priority.
        poll: Option<Poll> = per_mode, "", Allowed::Words("spin | yield");
    }

    /// `[sensor]`: measurement realism, off by default.
    SENSOR: SensorKeys = "sensor" {
        /// Encoder counts per revolution on the joint (0: no quantisation).
        encoder_counts_per_rev: u32 = (0), "", Allowed::Rule("0 (ideal) or 16..=4294967295 counts per revolution");
        /// Standard deviation of the noise added to q.
        q_noise_std_rad: f64 = (0.0), "rad", Allowed::closed(0.0, 0.1);
        /// Standard deviation of the noise added to q̇.
        qd_noise_std_rad_s: f64 = (0.0), "rad/s", Allowed::closed(0.0, 10.0);
        /// Seed of the noise (same seed, same run).
        seed: u64 = (1), "", Allowed::Any;
        /// Where the controller's joint rates come from.
        velocity: VelocitySource = (VelocitySource::Measured), "", Allowed::Words("measured | encoder-difference");
    }

    /// `[faults]`: how the loop reacts to a misbehaving peer, and fault injection.
    FAULTS: FaultKeys = "faults" {
        /// Realtime: missing torques in a row that declare the controller dead (the hold window).
        controller_silence_ticks: u32 = (100), "ticks", Allowed::closed(1.0, 1e6);
        /// Then the drives brake (τ = G(q) − D q̇) this long before the plant exits.
        safe_stop_ms: u32 = (100), "ms", Allowed::closed(0.0, 60_000.0);
        /// Brake damping D of the safe stop.
        brake_damping_nm_s: f64 = (2.0), "N m s/rad", Allowed::closed(0.0, 1000.0);
        /// Commands beyond ±τ_max (non-finite commands are always rejected).
        torque_limit: TorqueLimit = (TorqueLimit::Clamp), "", Allowed::Words("clamp | reject");
        /// Controller fault injection, for drills (K: the tick).
        inject: FaultInjection = (FaultInjection::None), "", Allowed::Words("none | nan-torque@K | panic@K | stall@K");
    }

    /// `[record]`: which per-tick files a run writes (docs/guide/run-folder.md).
    RECORD: RecordKeys = "record" {
        /// Write `trace.csv` (≈ 630 B a tick and law); replay needs it.
        trace: bool = (true), "", Allowed::Any;
        /// Write `<law>.timing.csv` in realtime and lockstep runs (≈ 106 B a tick).
        timing_csv: bool = (true), "", Allowed::Any;
        /// Realtime: record the kernel's scheduling on the loop's CPUs and name the cause of each missed or late tick (`--explain`; root and tracefs).
        explain: bool = (false), "", Allowed::Any;
    }

    /// `[link]`: one process of the run on another host (docs/guide/two-hosts.md).
    LINK: LinkKeys = "link" {
        /// Which process runs on the other host.
        remote: RemoteSide = "required", "", Allowed::Words("controller | plant");
        /// Where this host listens for the far side (TCP and UDP, one port).
        listen: String = "required", "", Allowed::Rule("IP:PORT of this host, e.g. 10.0.0.1:7447");
        /// Emulated one-way delay, each datagram, each direction.
        delay_us: f64 = (0.0), "us", Allowed::span(0.0, MAX_LINK_DELAY_US, LINK_DELAY_WORDS);
        /// Emulated one-way jitter: uniform in [0, this] on top of the delay.
        jitter_us: f64 = (0.0), "us", Allowed::span(0.0, MAX_LINK_DELAY_US, LINK_DELAY_WORDS);
        /// Emulated loss: the fraction of datagrams dropped.
        loss: f64 = (0.0), "", Allowed::span(0.0, 1.0, "0 <= loss <= 1 (a fraction of the datagrams)");
        /// Seed of the emulated jitter and loss (the far side draws with seed + 1).
        seed: u64 = (1), "", Allowed::Any;
        /// How long the near bridge polls for a reply before it blocks (the relay path's).
        spin_us: u32 = (0), "us", Allowed::closed(0.0, 1e6);
        /// How the loop's messages cross: socket to socket, or through both bridges.
        path: LinkPath = (LinkPath::Direct), "", Allowed::Words("direct | relay");
    }

    /// `[ros2]`: how deltaloop appears in a ROS 2 graph (docs/guide/ros2.md).
    ROS2: Ros2Keys = "ros2" {
        /// DDS domain.
        domain: Option<u16> = "`ROS_DOMAIN_ID`, else 0", "", Allowed::closed(0.0, 232.0);
        /// How far discovery reaches.
        range: Option<Ros2Range> = "`ROS_AUTOMATIC_DISCOVERY_RANGE`, else `localhost`", "", Allowed::Words("localhost | subnet");
        /// The live topics' namespace: `/<namespace>/<law>/joint_states`, …
        namespace: String = ("deltaloop".into()), "", Allowed::Rule(ROS_NAME_RULE);
        /// Publish every this many ticks.
        every: u32 = (10), "ticks", Allowed::closed(1.0, 1e6);
        /// `--controller ros2`: the robot's joint states, published by deltaloop.
        state_topic: String = ("/robot_joint_states".into()), "", Allowed::Rule(ROS_NAME_RULE);
        /// `--controller ros2`: the node's commands (JointState, `effort` in N m).
        command_topic: String = ("/robot_joint_commands".into()), "", Allowed::Rule("a ROS name other than state_topic's");
        /// The ROS 2 distribution whose graph format `ros_discovery_info` uses.
        distro: Ros2Distro = (Ros2Distro::Jazzy), "", Allowed::Words("humble | jazzy");
        /// `--controller ros2`: how long to wait for the node to appear.
        wait_s: f64 = (20.0), "s", Allowed::left_open(0.0, 25.0).note("(inside the 30 s handshake)");
    }
}

/// The key of a gain: every gain `0 <= value <= 1e9`, the nominal inertia `0 < m_bar <= 100`;
/// the unit is what the gain's doc line names after its comma (`…, N m/rad.`).
fn gain_key(field: &'static str, doc: &'static str) -> Key {
    let (unit, allowed) = match field {
        // As its errors have always written it.
        "m_bar" => ("kg m^2", Allowed::left_open(0.0, 100.0)),
        _ => (
            gain_unit(doc),
            Allowed::span(0.0, 1e9, "a finite number, 0 <= value <= 1e9"),
        ),
    };
    Key {
        table: "controller",
        field,
        ty: "Option<f64>",
        unit,
        allowed,
        default: KeyDefault::Said("the preset's"),
        doc,
    }
}

/// The unit in a gain's doc line: after its first `, `, before ` (` or the final `.`.
fn gain_unit(doc: &'static str) -> &'static str {
    let unit = doc.split_once(", ").map_or("", |(_, u)| u);
    let unit = unit.split_once(" (").map_or(unit, |(u, _)| u);
    unit.trim_end_matches('.')
}

macro_rules! gain_keys {
    ($(#[doc = $doc:literal] $name:ident,)*) => {
        /// `[controller]`'s override of each gain of the preset, one per gain of
        /// `with_controller_gains!`.
        pub fn gain_keys() -> Vec<Key> {
            vec![$(gain_key(stringify!($name), $doc),)*]
        }
    };
}

deltaloop_names::with_controller_gains!(gain_keys);

/// Every key of a scenario file, in the order of the key table.
pub fn all() -> Vec<Key> {
    [
        ROOT.keys(),
        SCENARIO.keys(),
        PLANT.keys(),
        CONTROLLER.keys(),
        gain_keys(),
        LOOP.keys(),
        LAYOUT.keys(),
        SENSOR.keys(),
        FAULTS.keys(),
        RECORD.keys(),
        LINK.keys(),
        ROS2.keys(),
    ]
    .concat()
}

/// The key table of docs/guide/scenario-files.md.
pub fn doc_table() -> String {
    let mut t = String::from(crate::key::TABLE_HEADER);
    for k in all() {
        t.push('\n');
        t.push_str(&k.table_row());
    }
    t
}

#[cfg(test)]
mod tests;
