//! The whole scenario file: [`RunConfig`], its sections (each in its own module of
//! `sections/`, re-exported here), and reading and writing it (parse, fill the preset and the
//! layouts, validate).

use crate::error::ConfigError;
use crate::files::read_text_file;
use crate::layout::Layout;
use crate::text::{clean_message, show_path, toml_error_position};
use deltaloop_names::{Compensation, ControllerParams};
use serde::{Deserialize, Serialize};
use std::path::Path;

pub use crate::sections::{
    ApplyTorque, ControllerSection, EmulationOutOfRange, FaultInjection, FaultSection,
    LinkEmulation, LinkPath, LinkSection, LoopSection, Overrun, PathKind, PlantSection,
    RecordSection, RemoteSide, Ros2Distro, Ros2Range, Ros2Section, ScenarioSection, Segment,
    SensorSection, TorqueLimit,
};

/// A whole scenario file. Sections other than `[scenario]` are optional.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RunConfig {
    /// Scenario name (run folders and reports use it); defaults to the file stem.
    #[serde(default)]
    pub name: String,

    /// Free text for reports.
    #[serde(
        default = "crate::keys::RootKeys::description",
        skip_serializing_if = "String::is_empty"
    )]
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

    /// The delay a compensated law predicts over, ns: `controller.compensate_delay_us` when
    /// set, else the transport delay.
    pub fn compensation_delay_ns(&self) -> u64 {
        self.controller
            .compensate_delay_us
            .map_or(self.transport_delay_ns(), |us| (us * 1e3).round() as u64)
    }

    /// Reference rows a controller reads beyond its state's tick: a compensated law at tick k
    /// reads rows k + d and k + d + 1 (d the whole ticks of the delay it predicts over); 0
    /// otherwise.
    pub fn reference_lookahead_ticks(&self) -> u64 {
        match self.controller.compensate {
            Compensation::None => 0,
            Compensation::Predict => self.compensation_delay_ns() / self.ts_ns() + 1,
        }
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::files::MAX_FILE_BYTES;
    use crate::test_util::{MIN, err};
    use deltaloop_names::{Law, Preset};

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
                timing_csv: true,
                explain: false
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
            e.contains("unknown field `traces`, expected one of `trace`, `timing_csv`, `explain`"),
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
