//! The laws' names and constants: which law runs ([`Law`]), its constants ([`ControllerParams`]) and
//! their presets ([`Preset`]), and where the rates come from ([`VelocitySource`]). Plain data with
//! serde derives, so the config schema can hold them and the laws run them, neither knowing of the other.

use serde::{Deserialize, Serialize};

crate::text_enum! {
    "kebab-case", "law";
    /// A control law (docs/controllers.md, "The laws").
    #[derive(PartialOrd, Ord)]
    pub enum Law {
        /// Time-delay control, u = 0.
        Tdc,
        /// TDE + integral sliding mode with a boundary layer (paper eq. 44).
        TdeIs,
        /// TDC + integral sliding mode + super-twisting (paper eq. 12–14), the paper's proposal.
        TdcIsSta,
        /// The same with the super-twisting term discretised implicitly (docs/controllers.md,
        /// "Super-twisting: explicit and implicit"); not a law of the paper.
        TdcIsIsta,
        /// PID baseline with a bumpless start; no TDE, no model.
        Pid,
    }
}

impl Law {
    /// The study's four laws: what a scenario file runs when it names none.
    pub const STUDY: [Law; 4] = [Law::Tdc, Law::TdeIs, Law::TdcIsSta, Law::Pid];

    /// The name the paper uses.
    pub fn paper_name(self) -> &'static str {
        match self {
            Law::Tdc => "TDC",
            Law::TdeIs => "TDC+IS",
            Law::TdcIsSta => "TDC+IS+STA",
            Law::TdcIsIsta => "TDC+IS+ISTA",
            Law::Pid => "PID",
        }
    }

    /// Whether the law uses time-delay estimation (so its TDE error is meaningful).
    pub fn uses_tde(self) -> bool {
        self != Law::Pid
    }
}

crate::text_enum! {
    "kebab-case", "preset";
    /// A named set of controller constants.
    #[derive(Default)]
    pub enum Preset {
        /// M̄ = 0.03 I kg m² (≈ 0.9 λmin(M) over the workspace), φ = 0.5 rad/s: the method as intended.
        #[default]
        Matched,
        /// M̄ = 3·10⁻⁴ I kg m² (the paper's Table I literally), φ = 100 rad/s: shows the limit cycle.
        Paper,
    }
}

/// Calls the macro `$then!` with every controller constant, each once with its doc (name, unit):
/// [`ControllerParams`] is made from it here, and the config's `[controller]` overrides, their
/// defaults from the preset and their range check from it in the config crate, so a new gain is
/// one line here and its value in [`ControllerParams::preset`].
#[macro_export]
macro_rules! with_controller_gains {
    ($then:ident) => {
        $then! {
            /// Nominal inertia M̄ (diagonal entry), kg m².
            m_bar,
            /// Integral-surface gain K_p, 1/s² (rad/s² per rad of integrated error per s).
            kp,
            /// Derivative gain K_d, 1/s.
            kd,
            /// Switching gain K_s of `tde-is`, rad/s².
            ks,
            /// Boundary-layer width φ of `tde-is`, rad/s (0 means sgn).
            phi,
            /// Super-twisting gain k1, rad^½/s^(3/2).
            k1,
            /// Super-twisting gain k2, rad/s³.
            k2,
            /// PID proportional gain P, N m/rad.
            pid_p,
            /// PID integral gain I, N m/(rad s).
            pid_i,
            /// PID derivative gain D, N m s/rad.
            pid_d,
        }
    };
}

macro_rules! controller_params {
    ($($(#[$doc:meta])* $name:ident,)*) => {
        /// The controller constants, all per joint (M̄ = m_bar · I).
        #[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
        #[serde(deny_unknown_fields)]
        pub struct ControllerParams {
            $($(#[$doc])* pub $name: f64,)*
        }

        impl ControllerParams {
            /// Every constant with its name, in declaration order.
            pub fn named(&self) -> Vec<(&'static str, f64)> {
                vec![$((stringify!($name), self.$name),)*]
            }
        }
    };
}

with_controller_gains!(controller_params);

impl ControllerParams {
    /// The constants of a preset (docs/controllers.md, Table I and the preset table).
    pub fn preset(p: Preset) -> Self {
        let (m_bar, phi) = match p {
            Preset::Matched => (0.03, 0.5),
            Preset::Paper => (3e-4, 100.0),
        };
        Self {
            m_bar,
            kp: 1800.0,
            kd: 1800.0,
            ks: 1460.0,
            phi,
            k1: 700.0,
            k2: 100.0,
            pid_p: 1800.0,
            pid_i: 6.7e4,
            pid_d: 16.0,
        }
    }
}

/// Where the controller's joint rates (and TDE accelerations) come from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "kebab-case")]
pub enum VelocitySource {
    /// The plant's measured q̇; a_j = (q̇_{j+1} − q̇_j)/Ts.
    #[default]
    Measured,
    /// Encoder only: q̇_k = (q_k − q_{k−1})/Ts and a_j = (q_{j+1} − 2q_j + q_{j−1})/Ts², paired
    /// with the mean applied torque of the two intervals (docs/controllers.md).
    EncoderDifference,
}

crate::text_enum! {
    "kebab-case", "compensation";
    /// How a law meets the delay between its measurement and the moment its torque acts
    /// (docs/controllers.md, "Delay compensation").
    #[derive(Default, PartialOrd, Ord)]
    pub enum Compensation {
        /// The law acts on the state it measured.
        #[default]
        None,
        /// The law acts on the state predicted for when its torque acts, over the torques in
        /// flight, with an inertia learned from measured data, and on the reference of that time.
        Predict,
    }
}

crate::text_enum! {
    "kebab-case", "delay source";
    /// Where a compensated law's delay D comes from (docs/controllers.md, "D in realtime").
    #[derive(Default)]
    pub enum DelaySource {
        /// D₀: `controller.compensate_delay_us`, else the run's transport delay.
        #[default]
        Config,
        /// Measured each tick from the drives' reports of applied torque, from D₀ up to D₀ + Ts.
        Measured,
    }
}

impl Compensation {
    /// What a law's name gets in tables and `sweep.csv` when it runs this way: "" or `+pred`.
    pub fn suffix(self) -> &'static str {
        match self {
            Compensation::None => "",
            Compensation::Predict => "+pred",
        }
    }
}

/// A law as tables, `sweep.csv` and figures name it: `tde-is`, or `tde-is+pred` compensated.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct LawVariant {
    pub law: Law,
    pub compensate: Compensation,
}

impl LawVariant {
    /// `law` as it runs with `compensate`.
    pub fn new(law: Law, compensate: Compensation) -> Self {
        Self { law, compensate }
    }

    /// What `law` runs as in a run that asks for `compensate`: a law without a TDE model
    /// (`pid`) has nothing to predict with and always runs uncompensated.
    pub fn as_run(law: Law, compensate: Compensation) -> Self {
        Self::new(
            law,
            if law.uses_tde() {
                compensate
            } else {
                Compensation::None
            },
        )
    }

    /// Parses `tde-is` or `tde-is+pred`; the error lists what is allowed.
    pub fn parse(s: &str) -> Result<Self, String> {
        let (name, compensate) = match s.strip_suffix(Compensation::Predict.suffix()) {
            Some(name) => (name, Compensation::Predict),
            None => (s, Compensation::None),
        };
        let law = Law::parse(name).map_err(|e| {
            format!(
                "{e}; a compensated law adds `{}`",
                Compensation::Predict.suffix()
            )
        })?;
        Ok(Self { law, compensate })
    }
}

impl From<Law> for LawVariant {
    fn from(law: Law) -> Self {
        Self::new(law, Compensation::None)
    }
}

impl std::fmt::Display for LawVariant {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.pad(&format!("{}{}", self.law.name(), self.compensate.suffix()))
    }
}

impl Serialize for LawVariant {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.collect_str(self)
    }
}

impl<'de> Deserialize<'de> for LawVariant {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let s = <std::borrow::Cow<'de, str>>::deserialize(d)?;
        Self::parse(&s).map_err(serde::de::Error::custom)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every law, compensated or not, reads back from its name; an unknown one says what is
    /// allowed.
    #[test]
    fn law_variants_round_trip_through_their_names() {
        for &law in Law::ALL {
            for &c in Compensation::ALL {
                let v = LawVariant::new(law, c);
                assert_eq!(LawVariant::parse(&v.to_string()), Ok(v));
            }
        }
        assert_eq!(
            LawVariant::new(Law::TdeIs, Compensation::Predict).to_string(),
            "tde-is+pred"
        );
        let e = LawVariant::parse("tde-is+smith").unwrap_err();
        assert!(
            e.contains("unknown law `tde-is+smith`") && e.contains("+pred"),
            "{e}"
        );
    }
}
