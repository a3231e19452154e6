//! Validation: every value of a parsed config against its allowed range, one section at a time,
//! with an error that names the key, the value and what is allowed.

use crate::error::ConfigError;
use crate::layout::{Layout, Poll};
use crate::schema::{
    ControllerSection, FaultSection, LinkEmulation, LinkSection, LoopSection, PathKind,
    PlantSection, Ros2Section, RunConfig, ScenarioSection, SensorSection, step_tick,
};
use crate::text::{MAX_ECHO_CHARS, escape_cut, show_num, show_str};
use std::fmt;

/// A [`ConfigError::Range`] for `key`; a long value is cut to [`MAX_ECHO_CHARS`] characters.
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

/// The longest hold, s: a day (a run streams, so only the disk bounds its length).
pub const MAX_HOLD_S: f64 = 86_400.0;

/// The most ticks a run may have, N = round((motion + hold)/Ts): 300 000 000, a day's hold and an
/// hour of motion at Ts = 0.3 ms (25 h in all; 50 min at the shortest period). Every
/// command that reads a config checks it in a few operations per segment, so a small file cannot
/// ask for billions of ticks that take hours to walk before anything starts.
pub const MAX_TICKS: u64 = 300_000_000;

/// What a scenario or sweep `name` may be: it names a folder under `runs/`.
pub const NAME_RULE: &str = "1 to 64 characters from A-Z a-z 0-9 . _ -, not starting with . or -";

/// Whether `name` may name a run folder: see [`NAME_RULE`].
pub fn name_is_valid(name: &str) -> bool {
    (1..=64).contains(&name.len())
        && !name.starts_with(['.', '-'])
        && name
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || matches!(b, b'.' | b'_' | b'-'))
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

/// A name shown in tables and files: at most 64 characters, printable, one line.
fn check_label(key: &str, label: &str) -> Result<(), ConfigError> {
    if label.chars().count() <= 64 && !label.chars().any(char::is_control) {
        Ok(())
    } else {
        Err(range(
            key,
            show_str(label),
            "at most 64 printable characters on one line",
        ))
    }
}

/// `v` is finite and `ok`, or the range error for `key`.
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
        if let Some(after) = self.overrun_after_us
            && !(1..=1_000_000).contains(&after)
        {
            return Err(range(
                "loop.overrun_after_us",
                after,
                "1 <= overrun_after_us <= 1000000 us",
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

/// Largest accepted emulated link delay or jitter (`link.delay_us`, `link.jitter_us`, the flags
/// `--link-delay-us`/`--link-jitter-us` and the sweep's `link_delay_us`/`link_jitter_us`), µs:
/// the one bound all of them check.
pub const MAX_LINK_DELAY_US: f64 = 1e6;

/// A field of a [`LinkEmulation`] outside its range: the field (`delay_us`, `jitter_us` or
/// `loss`), its value and what is allowed. The config names it `link.<field>`, the command line
/// `--link-<field>` ([`Self::flag`]).
#[derive(Clone, Debug, PartialEq)]
pub struct EmulationOutOfRange {
    pub field: &'static str,
    pub value: f64,
    pub allowed: String,
}

impl EmulationOutOfRange {
    /// The flag that sets the field: `--link-delay-us`, `--link-jitter-us`, `--link-loss`.
    pub fn flag(&self) -> String {
        format!("--link-{}", self.field.replace('_', "-"))
    }
}

impl std::fmt::Display for EmulationOutOfRange {
    /// As a command-line error: `--link-loss 2: allowed 0 <= loss <= 1 (…)`.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{} {}: allowed {}",
            self.flag(),
            show_num(self.value),
            self.allowed
        )
    }
}

impl LinkEmulation {
    /// The bounds of an emulation, wherever it comes from: delay and jitter 0..=
    /// [`MAX_LINK_DELAY_US`] µs, loss a fraction.
    pub fn check(&self) -> Result<(), EmulationOutOfRange> {
        let delay = || format!("0 <= value <= {MAX_LINK_DELAY_US} us");
        let ok = |v: f64, hi: f64| v.is_finite() && (0.0..=hi).contains(&v);
        for (field, value, hi) in [
            ("delay_us", self.delay_us, MAX_LINK_DELAY_US),
            ("jitter_us", self.jitter_us, MAX_LINK_DELAY_US),
            ("loss", self.loss, 1.0),
        ] {
            if !ok(value, hi) {
                let allowed = match field {
                    "loss" => "0 <= loss <= 1 (a fraction of the datagrams)".into(),
                    _ => delay(),
                };
                return Err(EmulationOutOfRange {
                    field,
                    value,
                    allowed,
                });
            }
        }
        Ok(())
    }
}

/// What a ROS name's tokens may hold: letters, digits and `_`, split by `/`, no token starting
/// with a digit, no empty token.
pub const ROS_NAME_RULE: &str =
    "ROS name tokens of A-Z a-z 0-9 _ split by /, none empty or starting with a digit";

/// Whether `name` (without a leading `/`) is made of ROS name tokens: see [`ROS_NAME_RULE`].
pub fn ros_name_is_valid(name: &str) -> bool {
    !name.is_empty()
        && name.len() <= 200
        && name.split('/').all(|t| {
            !t.is_empty()
                && !t.starts_with(|c: char| c.is_ascii_digit())
                && t.bytes().all(|b| b.is_ascii_alphanumeric() || b == b'_')
        })
}

impl Ros2Section {
    /// `[ros2]`: the domain, the names, the rate and the wait.
    fn validate(&self) -> Result<(), ConfigError> {
        if let Some(d) = self.domain.filter(|d| *d > 232) {
            return Err(range("ros2.domain", d, "0 <= domain <= 232"));
        }
        if !ros_name_is_valid(&self.namespace) {
            return Err(range(
                "ros2.namespace",
                show_str(&self.namespace),
                ROS_NAME_RULE,
            ));
        }
        for (key, t) in [
            ("ros2.state_topic", &self.state_topic),
            ("ros2.command_topic", &self.command_topic),
        ] {
            if !ros_name_is_valid(t.strip_prefix('/').unwrap_or(t)) {
                return Err(range(key, show_str(t), ROS_NAME_RULE));
            }
        }
        let topic = |t: &str| t.trim_start_matches('/').to_owned();
        if topic(&self.state_topic) == topic(&self.command_topic) {
            return Err(range(
                "ros2.command_topic",
                show_str(&self.command_topic),
                &format!(
                    "a topic other than ros2.state_topic's ({}): the robot would read its own states as commands",
                    show_str(&self.state_topic)
                ),
            ));
        }
        if !(1..=1_000_000).contains(&self.every) {
            return Err(range(
                "ros2.every",
                self.every,
                "1 <= every <= 1000000 ticks",
            ));
        }
        if !(self.wait_s > 0.0 && self.wait_s <= 25.0) {
            return Err(range(
                "ros2.wait_s",
                show_num(self.wait_s),
                "0 < wait_s <= 25 s (inside the 30 s handshake)",
            ));
        }
        Ok(())
    }
}

impl LinkSection {
    /// `[link]`: the address this host listens on, the emulation's and the spin's bounds (in
    /// realtime the spin is bounded by the torque budget too, where the mode is known).
    fn validate(&self) -> Result<(), ConfigError> {
        if self.listen.parse::<std::net::SocketAddr>().is_err() {
            return Err(range(
                "link.listen",
                show_str(&self.listen),
                "IP:PORT of this host, e.g. 10.0.0.1:7447",
            ));
        }
        self.emulation()
            .check()
            .map_err(|e| range(&format!("link.{}", e.field), show_num(e.value), &e.allowed))?;
        if self.spin_us > 1_000_000 {
            return Err(range(
                "link.spin_us",
                self.spin_us,
                "0 <= spin_us <= 1000000 us",
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
                &format!(
                    "at least one of {}",
                    deltaloop_names::allowed::<deltaloop_names::Law>()
                ),
            ));
        }
        for (i, l) in self.laws.iter().enumerate() {
            if self.laws[..i].contains(l) {
                return Err(range("controller.laws", l, "each law at most once"));
            }
        }
        check_command("controller.command", &self.command)?;
        check_label("controller.label", &self.label)?;
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
        for (name, v) in k.named().into_iter().filter(|(n, _)| *n != "m_bar") {
            check(
                &format!("controller.{name}"),
                v,
                (0.0..=1e9).contains(&v),
                "a finite number, 0 <= value <= 1e9",
            )?;
        }
        Ok(())
    }
}

impl Layout {
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
}

impl RunConfig {
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
        if let Some(ros2) = &self.ros2 {
            ros2.validate()?;
        }
        if let Some(link) = &self.link {
            link.validate()?;
        }
        self.validate_timing()
    }

    /// The keys bounded by the (already validated) control period Ts: every custom segment lasts
    /// at least one period (so the run has at least one tick, and no segment falls between two
    /// samples); the RK4 step Ts/substeps is at least 1 µs (the plant must keep up in realtime);
    /// a payload step falls within the run.
    fn validate_timing(&self) -> Result<(), ConfigError> {
        let ts = self.loop_.ts_s;
        self.check_ticks()?;
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

    /// At most [`MAX_TICKS`] ticks in the run, checked in closed form: the hold, then each custom
    /// segment's end (the segments and the hold so far); the error names the key that crosses
    /// the bound.
    fn check_ticks(&self) -> Result<(), ConfigError> {
        let ts = self.loop_.ts_s;
        let hold = self.scenario.hold_s;
        let ticks = |s: f64| (s / ts).round();
        let allowed = |reach: f64| {
            format!(
                "a run (motion + hold) of at most {MAX_TICKS} ticks, {} s at ts_s = {} s (here {reach:.0} ticks)",
                secs(MAX_TICKS as f64 * ts),
                secs(ts),
            )
        };
        let over = |s: f64| ticks(s) > MAX_TICKS as f64;
        if over(hold) {
            return Err(range(
                "scenario.hold_s",
                show_num(hold),
                &allowed(ticks(hold)),
            ));
        }
        let mut end = hold;
        for (i, seg) in self.scenario.segments.iter().enumerate() {
            end += seg.duration_s;
            if over(end) {
                return Err(range(
                    &format!("scenario.segments[{i}].duration_s"),
                    show_num(seg.duration_s),
                    &allowed(ticks(end)),
                ));
            }
        }
        let total = self.motion_duration_s() + hold;
        if over(total) {
            // A paper path (under 2 s) with a hold at the bound.
            return Err(range(
                "scenario.hold_s",
                show_num(hold),
                &allowed(ticks(total)),
            ));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_util::{MIN, err};
    use std::path::PathBuf;

    #[test]
    fn the_one_cpu_yield_layout_is_valid() {
        assert!(
            Layout::realtime_one_cpu_yield()
                .validate("loop.realtime", 3e-4)
                .is_ok()
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

    /// With one topic for both, the robot reads its own states as commands (no node needed).
    #[test]
    fn regression_a_state_topic_equal_to_the_command_topic_is_refused() {
        for (states, commands) in [("/robot_io", "/robot_io"), ("/robot_io", "robot_io")] {
            let toml = format!(
                "{MIN}[ros2]\nstate_topic = \"{states}\"\ncommand_topic = \"{commands}\"\n"
            );
            let e = RunConfig::from_toml_str(&toml, None).unwrap_err();
            assert_eq!(
                e.to_string(),
                format!(
                    "config key `ros2.command_topic` = \"{commands}\" is out of range: a topic other than ros2.state_topic's (\"{states}\"): the robot would read its own states as commands"
                )
            );
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

    /// Regression: 30 custom segments of an hour at `ts_s = 1e-5` (10.8 G ticks, a 3 KB file)
    /// were accepted and walked tick by tick for hours. The run's ticks are bounded, checked
    /// per segment; the error names the key that crosses the bound, its value and the bound.
    #[test]
    fn regression_a_3kb_config_asked_for_billions_of_ticks() {
        let seg = "{ from = [0.25, 0, -0.43], to = [-0.25, 0, -0.43], apex_m = 0.12, duration_s = 3600.0 }";
        let custom = |n: usize, ts: &str, hold: &str| {
            format!(
                "[scenario]\npath = \"custom\"\nhold_s = {hold}\nsegments = [{}]\n[loop]\nts_s = {ts}\ntorque_budget_us = 5\n",
                vec![seg; n].join(", ")
            )
        };
        let t0 = std::time::Instant::now();
        assert_eq!(
            err(&custom(30, "1e-5", "0")),
            "config key `scenario.segments[0].duration_s` = 3600 is out of range: a run (motion + hold) of at most 300000000 ticks, 3000 s at ts_s = 1e-5 s (here 360000000 ticks)"
        );
        assert!(t0.elapsed().as_secs_f64() < 0.5, "{:?}", t0.elapsed());
        // At 0.3 ms: 24 h of hold and an hour of motion fit, a second more does not.
        assert!(RunConfig::from_toml_str(&custom(1, "3e-4", "86400"), None).is_ok());
        assert!(RunConfig::from_toml_str(&custom(25, "3e-4", "0"), None).is_ok());
        assert_eq!(
            err(&custom(25, "3e-4", "1")),
            "config key `scenario.segments[24].duration_s` = 3600 is out of range: a run (motion + hold) of at most 300000000 ticks, 90000 s at ts_s = 0.0003 s (here 300003333 ticks)"
        );
        // A day's hold at a short period names the hold.
        assert!(
            err("[scenario]\npath = \"s1\"\nhold_s = 86400\n[loop]\nts_s = 1e-4\ntorque_budget_us = 50\n")
                .starts_with("config key `scenario.hold_s` = 86400 is out of range: a run (motion + hold) of at most 300000000 ticks, 30000 s at ts_s = 0.0001 s")
        );
        // A paper path's motion on top of a hold at the bound.
        assert!(
            err("[scenario]\npath = \"s3\"\nhold_s = 90000\n")
                .contains("`scenario.hold_s` = 90000")
        );
    }
}
