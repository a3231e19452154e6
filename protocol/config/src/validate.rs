//! Validation of a whole config: each section against its keys' declarations (each section's
//! `validate`, in `sections/`), then the keys the control period bounds and the run's length;
//! the checks the sections share. The limits (`MAX_*`, [`NAME_RULE`]) are in `limits`, re-exported here.

use crate::error::ConfigError;
use crate::key::range;
use crate::schema::{RunConfig, step_tick};
use crate::text::{show_num, show_str};

pub(crate) use crate::limits::{COMMAND_RULE, LABEL_RULE};
pub use crate::limits::{
    MAX_HOLD_S, MAX_LINK_DELAY_US, MAX_SUBSTEPS, MAX_TDE_DELAY, MAX_TICKS, MAX_TRANSPORT_DELAY,
    MAX_TRANSPORT_DELAY_US, NAME_RULE, ROS_NAME_RULE,
};

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
pub(crate) fn check_command(key: &str, cmd: &[String]) -> Result<(), ConfigError> {
    match cmd
        .iter()
        .find(|a| a.is_empty() || a.contains('\0') || a.len() > 4096)
    {
        Some(bad) => Err(range(key, show_str(bad), COMMAND_RULE)),
        None => Ok(()),
    }
}

/// A name shown in tables and files: at most 64 characters, printable, one line.
pub(crate) fn check_label(key: &str, label: &str) -> Result<(), ConfigError> {
    if label.chars().count() <= 64 && !label.chars().any(char::is_control) {
        Ok(())
    } else {
        Err(range(key, show_str(label), LABEL_RULE))
    }
}

/// `v` is finite and `ok`, or the range error for `key`.
pub(crate) fn check(key: &str, v: f64, ok: bool, allowed: &str) -> Result<(), ConfigError> {
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
    use crate::layout::Layout;
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

    /// The delay a prediction walks, given to a run that predicts nothing, is said, not ignored;
    /// with `compensate = "predict"` both keys are taken.
    #[test]
    fn the_compensation_delay_keys_need_a_compensated_law() {
        for (keys, says) in [
            (
                "compensate_delay_us = 150.0\n",
                "`controller.compensate_delay_us` = 150 is out of range: it applies to a compensated law only",
            ),
            (
                "compensate_delay = \"measured\"\n",
                "`controller.compensate_delay` = \"measured\" is out of range: it applies to a compensated law only",
            ),
        ] {
            let e =
                RunConfig::from_toml_str(&format!("{MIN}[controller]\n{keys}"), None).unwrap_err();
            assert!(e.to_string().contains(says), "{e}");
            let c = RunConfig::from_toml_str(
                &format!("{MIN}[controller]\ncompensate = \"predict\"\n{keys}"),
                None,
            );
            assert!(c.is_ok(), "{c:?}");
        }
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
