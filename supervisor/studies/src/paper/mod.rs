//! `deltaloop paper`: the study's Tables II–IV and Figures 2–9 regenerated from our runs, under
//! both presets, next to the paper's published numbers, with an honest verdict.
//!
//! Every run goes through [`run::run`], so each scenario × preset also leaves a normal run folder
//! (`<preset>/<scenario>/`: trace, summary, report) next to the figures.

use anyhow::{Context, Result};
use deltaloop_config::LoopMode;
use deltaloop_config::PathKind;
use deltaloop_config::{ControllerParams, Law, Preset, RunConfig};
use deltaloop_report::plot::{self, Panel, Series, Series3};
use deltaloop_report::report::{limit_cycle, paper_rms, paper_table, rms_fig};
use deltaloop_runner::lawrun::LawRun;
use deltaloop_runner::run;
use deltaloop_study::Study;
use deltaloop_study::analysis::{Mismatch, mismatch};
use deltaloop_study::record::metrics::LawMetrics;
use deltaloop_study::record::{RunStatus, sensitivity};
use serde::Serialize;
use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

mod plots;
pub mod robust;
mod text;

use plots::figures;
pub use plots::{STA_FIGURE, sta_window};
pub use text::{fmt_rms, sta_row, terminal};
use text::{published_rms, report};

/// The laws of the study: the paper's pair first, then our baselines. The paper's tables,
/// verdicts and figures are about these four.
pub const LAWS: [Law; 4] = [Law::TdeIs, Law::TdcIsSta, Law::Tdc, Law::Pid];

/// The laws of the "Explicit vs implicit super-twisting" section: `tde-is`, the paper's explicit
/// super-twisting law and our implicit one (docs/controllers.md).
pub const STA_LAWS: [Law; 3] = [Law::TdeIs, Law::TdcIsSta, Law::TdcIsIsta];

/// Every law a case runs: [`LAWS`], then the implicit super-twisting law.
pub fn case_laws() -> Vec<Law> {
    LAWS.into_iter().chain([Law::TdcIsIsta]).collect()
}

/// Length of the explicit-vs-implicit torque window, s.
pub const STA_WINDOW_S: f64 = 0.05;

/// The shipped scenario files (embedded, so the command works from any directory).
const CONFIGS: [(Preset, &str, &str); 6] = [
    (
        Preset::Matched,
        "s1-nominal",
        include_str!("../../../../configs/s1-nominal.toml"),
    ),
    (
        Preset::Matched,
        "s2-fast",
        include_str!("../../../../configs/s2-fast.toml"),
    ),
    (
        Preset::Matched,
        "s3-composite",
        include_str!("../../../../configs/s3-composite.toml"),
    ),
    (
        Preset::Paper,
        "s1-nominal",
        include_str!("../../../../configs/paper/s1-nominal.toml"),
    ),
    (
        Preset::Paper,
        "s2-fast",
        include_str!("../../../../configs/paper/s2-fast.toml"),
    ),
    (
        Preset::Paper,
        "s3-composite",
        include_str!("../../../../configs/paper/s3-composite.toml"),
    ),
];

/// One scenario under one preset.
#[derive(Debug, Serialize)]
pub struct Case {
    pub preset: Preset,
    pub scenario: PathKind,
    pub paper_table: &'static str,
    /// Metrics per law.
    pub laws: BTreeMap<Law, LawMetrics>,
    pub mismatch: Mismatch,
    /// tdc-is-sta RMS / tde-is RMS per joint (< 1: the proposal is better).
    pub sta_over_is_rms: [f64; 3],
    /// The run folder of this case, relative to the paper folder.
    pub run_folder: String,
    /// Figure stems (without extension), relative to the paper folder.
    pub figures: Vec<String>,
    /// The controller constants the case ran with (the report quotes them; not in summary.json).
    #[serde(skip)]
    pub params: ControllerParams,
    /// The drive torque limit the case ran with, N m (as `params`).
    #[serde(skip)]
    pub tau_max_nm: f64,
}

/// `summary.json` of the paper folder.
#[derive(Debug, Serialize)]
pub struct PaperSummary {
    pub mode: LoopMode,
    pub command: String,
    pub elapsed_s: f64,
    /// The paper's published RMS (rad) per scenario and law (TDC+IS = `tde-is`, TDC+IS+STA = `tdc-is-sta`).
    pub paper_rms_rad: BTreeMap<PathKind, BTreeMap<Law, [f64; 3]>>,
    pub cases: Vec<Case>,
    /// The robustness table (sensor-noise seeds, realtime runs), unless `--seeds 0`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub robustness: Option<robust::Robustness>,
}

/// A run's per-tick value of one joint: (run, record index, joint) → value.
type PerTick<'a> = &'a dyn Fn(&LawRun, usize, usize) -> f64;

/// Runs the study into `out`.
/// `out` must be empty or new unless `force`.
/// What `deltaloop paper` runs besides the cases.
#[derive(Clone, Copy, Debug)]
pub struct Options {
    /// Each case's round-off twins (not in realtime).
    pub sensitivity: bool,
    /// Sensor-noise seeds of the robustness table (0: no table).
    pub seeds: u32,
    /// Realtime runs per scenario of the robustness table (0: none).
    pub realtime_runs: u32,
}

impl Default for Options {
    fn default() -> Self {
        Self {
            sensitivity: true,
            seeds: robust::SEEDS,
            realtime_runs: robust::REALTIME_RUNS,
        }
    }
}

pub fn run(
    mode: LoopMode,
    opts: Options,
    out: &Path,
    force: bool,
    command: &str,
    progress: bool,
) -> Result<PaperSummary> {
    let _folder = deltaloop_report::RunFolder::claim(out, force)?;
    let t0 = Instant::now();
    std::fs::create_dir_all(out).with_context(|| format!("cannot create {}", out.display()))?;
    let bar = deltaloop_report::progress_bar(CONFIGS.len(), progress);
    let mut cases = Vec::new();
    for (preset, name, text) in CONFIGS {
        bar.set_message(format!(
            "{name} ({} preset, {} mode)",
            preset.name(),
            mode.name()
        ));
        let twins = opts.sensitivity && mode != LoopMode::Realtime;
        cases.push(run_case(preset, name, text, mode, twins, out, command)?);
        bar.inc(1);
    }
    bar.finish_and_clear();
    let robustness = if opts.seeds > 0 {
        Some(robust::run(out, opts.seeds, opts.realtime_runs, progress)?)
    } else {
        None
    };
    let summary = PaperSummary {
        mode,
        command: command.into(),
        elapsed_s: t0.elapsed().as_secs_f64(),
        paper_rms_rad: published_rms(),
        cases,
        robustness,
    };
    deltaloop_report::write_text(
        &out.join("summary.json"),
        &serde_json::to_string_pretty(&summary)?,
    )?;
    deltaloop_report::write_text(&out.join("report.md"), &report(&summary))?;
    Ok(summary)
}

/// One shipped scenario file (`name`, `text`) under `preset`, every law of [`LAWS`]: its run
/// folder `<preset>/<scenario>/` and its figures in `out`.
fn run_case(
    preset: Preset,
    name: &str,
    text: &str,
    mode: LoopMode,
    sensitivity: bool,
    out: &Path,
    command: &str,
) -> Result<Case> {
    let mut cfg = RunConfig::from_toml_str(text, Some(Path::new(&format!("{name}.toml"))))?;
    cfg.controller.laws = case_laws();
    let path = cfg.scenario.path;
    let scn = path.name();
    let table = paper_table(cfg.scenario.path).unwrap_or("-");
    let tau_max_nm = cfg.plant.tau_max_nm;
    let rel = PathBuf::from(preset.name()).join(scn);
    let o = run::run(run::RunRequest {
        out: Some(out.join(&rel)),
        keep_records: true,
        sensitivity,
        ..run::RunRequest::new(cfg, mode, command)
    })?;
    let title = format!("{} ({} preset)", scn.to_uppercase(), preset.name());
    let figs = figures(
        &o.study,
        &o.runs,
        out,
        &format!("fig-{scn}-{}", preset.name()),
        &title,
    )?;
    let laws: BTreeMap<Law, LawMetrics> = o.metrics.into_iter().map(|m| (m.law, m)).collect();
    let (is, sta) = (&laws[&Law::TdeIs].rms_rad, &laws[&Law::TdcIsSta].rms_rad);
    Ok(Case {
        preset,
        scenario: path,
        paper_table: table,
        sta_over_is_rms: [sta[0] / is[0], sta[1] / is[1], sta[2] / is[2]],
        mismatch: mismatch(&o.study.robot, &o.study.reference, &o.study.params),
        laws,
        run_folder: rel.display().to_string(),
        figures: figs,
        params: o.study.params,
        tau_max_nm,
    })
}

#[cfg(test)]
mod tests {
    use super::text::*;
    use super::*;

    /// The limit-cycle paragraph quotes the k1, clamp and φ the case ran with, not fixed numbers.
    #[test]
    fn limit_cycle_text_quotes_the_constants_the_case_ran_with() {
        let (preset, name, text) = CONFIGS[3];
        assert_eq!((preset, name), (Preset::Paper, "s1-nominal"));
        let text = text
            .replace("tau_max_nm = 100.0", "tau_max_nm = 90.0")
            .replace(
                "preset = \"paper\"",
                "preset = \"paper\"\nk1 = 650.0\nphi = 80.0",
            );
        assert!(text.contains("tau_max_nm = 90.0") && text.contains("k1 = 650.0"));
        let out = std::env::temp_dir().join(format!("deltaloop-paper-k1-{}", std::process::id()));
        let case = run_case(preset, name, &text, LoopMode::Inproc, false, &out, "test");
        let _ = std::fs::remove_dir_all(&out);
        let summary = PaperSummary {
            mode: LoopMode::Inproc,
            command: "test".into(),
            elapsed_s: 0.0,
            paper_rms_rad: published_rms(),
            cases: vec![case.unwrap()],
            robustness: None,
        };
        let md = report(&summary);
        for quoted in [
            "(k1 = 650, v̇ = k2·sgn s)",
            "hits the ±90 N m clamp",
            "(φ = 80 rad/s)",
        ] {
            assert!(md.contains(quoted), "missing `{quoted}` in\n{md}");
        }
    }

    #[test]
    fn published_rms_is_keyed_by_scenario_name() {
        let p = published_rms();
        let keys: Vec<&str> = p.keys().map(|k| k.name()).collect();
        assert_eq!(keys, ["s1", "s2", "s3"]);
        assert_eq!(p[&PathKind::S2][&Law::TdcIsSta], [0.0044, 0.0047, 0.0047]);
        // In summary.json the keys are the config words.
        let json = serde_json::to_value(&p).unwrap();
        assert_eq!(json["s2"]["tdc-is-sta"][0], 0.0044);
    }
}

/// A constant for prose: plain from 0.01 up (`0.03`), else `m·10ⁿ` with a superscript exponent
/// (`3·10⁻⁴`).
fn fmt_unicode_sci(x: f64) -> String {
    if x == 0.0 || x.abs() >= 0.01 {
        return format!("{x}");
    }
    let e = x.abs().log10().floor() as i32;
    let m = x / 10f64.powi(e);
    let sup: String = e
        .to_string()
        .chars()
        .map(|c| match c {
            '-' => '⁻',
            d => ['⁰', '¹', '²', '³', '⁴', '⁵', '⁶', '⁷', '⁸', '⁹']
                [d.to_digit(10).unwrap_or(0) as usize],
        })
        .collect();
    format!("{}·10{sup}", (m * 1e6).round() / 1e6)
}

#[cfg(test)]
mod unicode_sci_tests {
    use super::fmt_unicode_sci;

    #[test]
    fn prose_constants_read_as_in_the_report() {
        assert_eq!(fmt_unicode_sci(0.03), "0.03");
        assert_eq!(fmt_unicode_sci(3e-4), "3·10⁻⁴");
        assert_eq!(fmt_unicode_sci(2.5e-12), "2.5·10⁻¹²");
    }
}
