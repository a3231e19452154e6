//! `[controller]`: the laws, the preset, the TDE delay and the gains' overrides, their keys and
//! their checks; what a run calls a controller started by command.

use crate::error::ConfigError;
use crate::key::range;
use crate::keys::{CONTROLLER, ControllerKeys, gain_keys};
use crate::text::show_path;
use crate::validate::{check_command, check_label};
use deltaloop_names::{Compensation, ControllerParams, DelaySource, Law, Preset};
use serde::{Deserialize, Serialize};
use std::path::Path;

macro_rules! controller_section {
    ($($(#[$doc:meta])* $name:ident,)*) => {
        /// `[controller]`: laws, preset, TDE delay, and per-key overrides of the preset's constants
        /// (None: the preset's value; every gain of [`ControllerParams`], with its unit there).
        #[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
        #[serde(deny_unknown_fields)]
        pub struct ControllerSection {
            /// The preset the constants start from.
            #[serde(default = "ControllerKeys::preset")]
            pub preset: Preset,

            /// The laws to run (each is one run of the scenario).
            #[serde(default = "ControllerKeys::laws")]
            pub laws: Vec<Law>,

            /// TDE delay ℓ (L = ℓ·Ts), ticks, ≥ 1.
            #[serde(default = "ControllerKeys::tde_delay_samples")]
            pub tde_delay_samples: u32,

            /// Delay compensation (docs/controllers.md, "Delay compensation"): `none`, or
            /// `predict`, the law on the state predicted for when its torque acts.
            #[serde(default = "ControllerKeys::compensate")]
            pub compensate: Compensation,

            /// The delay D the prediction of `compensate = "predict"` assumes, µs; None: the run's
            /// transport delay d·Ts + `plant.transport_delay_us` (docs/controllers.md, "D").
            #[serde(default, skip_serializing_if = "Option::is_none")]
            pub compensate_delay_us: Option<f64>,

            /// Where D comes from: `config` (D₀ above), or `measured` each tick from the drives'
            /// reports of applied torque, between D₀ and D₀ + Ts (docs/controllers.md, "D in
            /// realtime").
            #[serde(default = "ControllerKeys::compensate_delay")]
            pub compensate_delay: DelaySource,

            /// Extra wall time the controller process spends before each reply, µs (realtime: real
            /// misses; lockstep: only slower; inproc: no effect).
            #[serde(default = "ControllerKeys::compute_delay_us")]
            pub compute_delay_us: u32,

            /// Run this executable (program, then arguments) in place of the built-in
            /// `deltaloop-controller` in the process modes; it gets the same arguments after these
            /// (`--run-id`, `--config`, `--mode`, `--law`) and must speak the wire contract
            /// (docs/protocol.md). Empty: the built-in controller.
            #[serde(default = "ControllerKeys::command", skip_serializing_if = "Vec::is_empty")]
            pub command: Vec<String>,

            /// What the run calls the controller that ran (the tables, `summary.json`,
            /// `report.md`), beside the law it answered as. Empty: the file name of `command`'s
            /// program (its script's, for an interpreter), or none for the built-in controller.
            #[serde(default = "ControllerKeys::label", skip_serializing_if = "String::is_empty")]
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
            pub(crate) fn resolve_preset(&mut self) {
                let p = self.params();
                $(self.$name = Some(p.$name);)*
            }
        }
    };
}

deltaloop_names::with_controller_gains!(controller_section);

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

impl ControllerSection {
    /// `[controller]`: compute delay, the law list, the TDE delay, and the resolved constants.
    pub(crate) fn validate(&self) -> Result<(), ConfigError> {
        CONTROLLER
            .compute_delay_us
            .check_int(self.compute_delay_us.into())?;
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
        if let Some(us) = self.compensate_delay_us {
            CONTROLLER.compensate_delay_us.check(us)?;
        }
        // The delay a prediction walks means nothing without one: said, not ignored.
        if self.compensate == Compensation::None {
            let set = match (self.compensate_delay_us, self.compensate_delay) {
                (Some(us), _) => {
                    Some(("controller.compensate_delay_us", crate::text::show_num(us)))
                }
                (None, DelaySource::Measured) => {
                    Some(("controller.compensate_delay", "\"measured\"".to_string()))
                }
                (None, DelaySource::Config) => None,
            };
            if let Some((key, value)) = set {
                return Err(range(
                    key,
                    value,
                    "it applies to a compensated law only: set controller.compensate = \"predict\" (flag --compensate predict), or leave it out",
                ));
            }
        }
        check_command("controller.command", &self.command)?;
        check_label("controller.label", &self.label)?;
        CONTROLLER
            .tde_delay_samples
            .check_int(self.tde_delay_samples.into())?;
        // Both lists follow `with_controller_gains!`, in its order.
        for ((name, v), key) in self.params().named().into_iter().zip(gain_keys()) {
            debug_assert_eq!(name, key.field);
            key.check(v)?;
        }
        Ok(())
    }
}
