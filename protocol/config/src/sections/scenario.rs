//! `[scenario]`: the reference motion, its keys and their checks.

use crate::error::ConfigError;
use crate::key::range;
use crate::keys::{SCENARIO, ScenarioKeys};
use crate::validate::check;
use serde::{Deserialize, Serialize};

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
    #[serde(
        default = "ScenarioKeys::segments",
        skip_serializing_if = "Vec::is_empty"
    )]
    pub segments: Vec<Segment>,

    /// Extra time after the motion ends, s (the reference holds its end point). Metrics cover the
    /// whole run.
    #[serde(default = "ScenarioKeys::hold_s")]
    pub hold_s: f64,
}

impl ScenarioSection {
    /// `[scenario]`: the hold, and the segments (only, and at least one, with `custom`).
    pub(crate) fn validate(&self) -> Result<(), ConfigError> {
        SCENARIO.hold_s.check(self.hold_s)?;
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
