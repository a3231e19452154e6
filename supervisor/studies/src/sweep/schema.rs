//! The sweep file: its schema, the checks run before any point (counts, caps, duplicate axis
//! values, a safe name), loading it with its base config, and the grid of points it spans.

use anyhow::{Result, bail};
use deltaloop_config::{self as cfgfile, PathKind};
use deltaloop_config::{Compensation, ConfigError, Law, LawVariant, LoopMode, Preset, RunConfig};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// The sweep file.
#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct SweepFile {
    pub name: String,
    #[serde(default)]
    pub description: String,
    /// Scenario config every point starts from (plant, loop, sensor), relative to the sweep file.
    /// Its path and preset are replaced by the axes below.
    pub base: PathBuf,
    /// Mode of the deterministic axes: `inproc` or `lockstep`.
    #[serde(default)]
    pub mode: LoopMode,
    pub scenarios: Vec<PathKind>,
    pub presets: Vec<Preset>,
    pub laws: Vec<Law>,
    /// Each law with and/or without delay compensation (`controller.compensate`): a compensated
    /// point's rows name the law `<law>+pred`. `pid`, which has no TDE model to predict with,
    /// runs uncompensated only. Default `["none"]`.
    #[serde(default = "uncompensated", skip_serializing_if = "is_uncompensated")]
    pub compensate: Vec<Compensation>,
    pub tde_delay_samples: Vec<u32>,
    pub transport_delay_samples: Vec<u32>,
    /// Sub-tick transport delay axis, µs: each value runs every law × scenario × preset at the
    /// first ℓ and d above, with `plant.transport_delay_us` set. Empty: none.
    #[serde(default)]
    pub transport_delay_us: Vec<f64>,
    /// Realtime axis: each value runs every law × scenario × preset in realtime mode at the first
    /// ℓ and d above. Empty: no realtime runs.
    #[serde(default)]
    pub compute_delay_us: Vec<u32>,
    /// Emulated network delay axis, µs each way: each value runs every law × scenario × preset
    /// in realtime at the first ℓ and d above, with the controller across `deltaloop-bridge`
    /// over this host's loopback (its own iceoryx2 root, a free port), the bridge delaying each
    /// datagram by this much; next to each, the same config in-process with `transport_delay_us`
    /// = the run's measured median arrival. Empty: none.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub link_delay_us: Vec<f64>,
    /// Emulated jitter of every link point, µs each way: uniform in [0, this] on top of the delay.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub link_jitter_us: f64,
    /// Emulated loss of every link point: the fraction of datagrams dropped, each direction.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub link_loss: f64,
    /// Runs per point, with sensor-noise seeds `sensor.seed` of the base, + 1, …, + repeats − 1
    /// (in realtime, that many runs); each row holds the means with standard deviations and
    /// t-based 95 % confidence intervals. 1..=1000, default 1.
    #[serde(default = "one")]
    pub repeats: u32,
    /// Run each point's round-off twin (the first seed's; not in realtime) and report how far
    /// its metrics move. Default true.
    #[serde(default = "yes")]
    pub sensitivity: bool,
}

fn uncompensated() -> Vec<Compensation> {
    vec![Compensation::None]
}

fn is_uncompensated(v: &Vec<Compensation>) -> bool {
    *v == uncompensated()
}

/// The law variants a sweep runs, in its order: each law × each `compensate` it can take.
pub fn variants(sw: &SweepFile) -> Vec<LawVariant> {
    sw.laws
        .iter()
        .flat_map(|&law| {
            sw.compensate
                .iter()
                .filter(move |&&c| LawVariant::as_run(law, c).compensate == c)
                .map(move |&c| LawVariant::new(law, c))
        })
        .collect()
}

fn one() -> u32 {
    1
}

fn yes() -> bool {
    true
}

fn is_zero(x: &f64) -> bool {
    *x == 0.0
}

/// The emulated link of a point of the `link_delay_us` axis (each direction).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Link {
    pub delay_us: f64,
    pub jitter_us: f64,
    pub loss: f64,
}

/// Most repeats a sweep point may run.
pub const MAX_REPEATS: u32 = 1000;

/// One point's parameters.
#[derive(Debug, Clone, PartialEq)]
pub struct Job {
    pub(super) scenario: PathKind,
    pub(super) preset: Preset,
    pub(super) law: Law,
    pub(super) compensate: Compensation,
    pub(super) ell: u32,
    pub(super) d: u32,
    /// Which axis the point is of, and its value there.
    pub(super) kind: PointKind,
}

/// The axes of a sweep beyond the ℓ × d grid, one variant each: what a point of that axis varies.
/// A new axis is a variant here, its key in [`SweepFile`] and its points in [`expand`], and its
/// setting in `point_config` (point.rs); its columns in the row.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum PointKind {
    /// A grid point: ℓ × d, in the sweep's mode.
    Grid,
    /// The `transport_delay_us` axis: this much transport delay beyond whole ticks, µs.
    SubTick { us: f64 },
    /// The `compute_delay_us` axis: realtime, with this extra controller compute per tick, µs.
    Compute { us: u32 },
    /// The `link_delay_us` axis: realtime, the controller across the bridge.
    Link(Link),
}

impl PointKind {
    /// The point runs in realtime whatever the sweep's mode.
    pub fn realtime(self) -> bool {
        match self {
            PointKind::Grid | PointKind::SubTick { .. } => false,
            PointKind::Compute { .. } | PointKind::Link(_) => true,
        }
    }

    /// `plant.transport_delay_us` of the point, µs. Each axis is named in each of these three
    /// (no catch-all arm): a new axis is a compile error here until it says what it sets.
    pub fn transport_us(self) -> f64 {
        match self {
            PointKind::SubTick { us } => us,
            PointKind::Grid | PointKind::Compute { .. } | PointKind::Link(_) => 0.0,
        }
    }

    /// `controller.compute_delay_us` of the point, µs.
    pub fn compute_us(self) -> u32 {
        match self {
            PointKind::Compute { us } => us,
            PointKind::Grid | PointKind::SubTick { .. } | PointKind::Link(_) => 0,
        }
    }

    /// The emulated link of a link point.
    pub fn link(self) -> Option<Link> {
        match self {
            PointKind::Link(l) => Some(l),
            PointKind::Grid | PointKind::SubTick { .. } | PointKind::Compute { .. } => None,
        }
    }
}

impl Job {
    /// The law as the point runs it, `<law>+pred` when compensated.
    pub fn variant(&self) -> LawVariant {
        LawVariant::new(self.law, self.compensate)
    }
}

impl std::fmt::Display for Job {
    /// `s1/matched/tdc ℓ=1 d=0`, and `c=200us (realtime)` for the compute-delay axis.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{}/{}/{} ℓ={} d={}",
            self.scenario.name(),
            self.preset.name(),
            self.variant(),
            self.ell,
            self.d
        )?;
        match self.kind {
            PointKind::Grid => Ok(()),
            PointKind::SubTick { us } => write!(f, " D+={us}us"),
            PointKind::Compute { us } => write!(f, " c={us}us (realtime)"),
            PointKind::Link(l) => write!(f, " link={}us (realtime, across the bridge)", l.delay_us),
        }
    }
}

/// The first value listed twice on a sweep axis, if any (linear: an axis may list thousands).
fn repeated(values: &[String]) -> Option<&String> {
    let mut seen = std::collections::HashSet::with_capacity(values.len());
    values.iter().find(|v| !seen.insert(v.as_str()))
}

/// Most points a sweep may have. The plan, a merge's rows and `sweep plan --json` (what a
/// cluster driver reads) hold every point in memory, a few hundred bytes each: 10⁵ points are
/// tens of MB, and ≈ 40 CPU-minutes of the cheapest (in-process, ≈ 24 ms each) or days of
/// realtime ones. That covers the largest study docs/guide/cluster.md plans (a 10⁵-point Monte Carlo on a
/// cluster); a grid beyond it is a typo in an axis, or several sweeps. Checked before anything
/// is expanded (regression: a 118 KB file of about 10⁸ points aborted `sweep plan` and
/// `sweep merge` on allocation).
pub const MAX_POINTS: u64 = 100_000;

/// How many points a sweep expands to: scenarios × presets × laws (each compensated or not, as
/// `compensate` says) × (ℓ × d + the sub-tick delays above 0 + the compute delays), in checked
/// arithmetic; the error names the axes, their product and [`MAX_POINTS`].
fn point_count(sw: &SweepFile) -> Result<u64> {
    let n = |v: usize| v as u64;
    let us = sw.transport_delay_us.iter().filter(|&&us| us > 0.0).count();
    let count = n(sw.tde_delay_samples.len())
        .checked_mul(n(sw.transport_delay_samples.len()))
        .and_then(|g| g.checked_add(n(us)))
        .and_then(|g| g.checked_add(n(sw.compute_delay_us.len())))
        .and_then(|g| g.checked_add(n(sw.link_delay_us.len())))
        .and_then(|g| g.checked_mul(n(variants(sw).len())))
        .and_then(|g| g.checked_mul(n(sw.presets.len())))
        .and_then(|g| g.checked_mul(n(sw.scenarios.len())));
    match count {
        Some(c) if c <= MAX_POINTS => Ok(c),
        _ => bail!(
            "the sweep has {} points: scenarios {} × presets {} × laws {} × (tde_delay_samples {} × transport_delay_samples {} + transport_delay_us {us} + compute_delay_us {}{}), more than the {MAX_POINTS} a sweep may have: split it into several sweep files",
            count.map_or_else(|| "more than 2^64".to_string(), |c| c.to_string()),
            sw.scenarios.len(),
            sw.presets.len(),
            variants(sw).len(),
            sw.tde_delay_samples.len(),
            sw.transport_delay_samples.len(),
            sw.compute_delay_us.len(),
            match sw.link_delay_us.len() {
                0 => String::new(),
                l => format!(" + link_delay_us {l}"),
            }
        ),
    }
}

/// Checks the sweep file's own keys: name, mode, and every axis non-empty and without repeats
/// (a repeated value would run the same point twice, and `run` rejects a repeated law too).
fn check(sw: &SweepFile) -> Result<()> {
    if !cfgfile::name_is_valid(&sw.name) {
        bail!(
            "sweep key `name` = {} is out of range: {}",
            cfgfile::show_str(&sw.name),
            cfgfile::NAME_RULE
        );
    }
    if sw.mode == LoopMode::Realtime {
        bail!(
            "sweep key `mode` = \"{}\" is out of range: inproc or lockstep (the compute_delay_us axis runs in realtime by itself)",
            sw.mode
        );
    }
    if let Some(&us) = sw
        .transport_delay_us
        .iter()
        .find(|us| !(us.is_finite() && (0.0..=cfgfile::MAX_TRANSPORT_DELAY_US).contains(*us)))
    {
        bail!(
            "sweep key `transport_delay_us` lists {}: each value 0 <= us <= {} µs",
            cfgfile::show_num(us),
            cfgfile::MAX_TRANSPORT_DELAY_US
        );
    }
    check_link(sw)?;
    if !(1..=MAX_REPEATS).contains(&sw.repeats) {
        bail!(
            "sweep key `repeats` = {} is out of range: 1..={MAX_REPEATS} runs per point",
            sw.repeats
        );
    }
    point_count(sw)?;
    let axes: [(&str, Vec<String>, bool); 9] = [
        (
            "scenarios",
            sw.scenarios.iter().map(|s| s.name().to_string()).collect(),
            true,
        ),
        (
            "presets",
            sw.presets.iter().map(|p| p.name().to_string()).collect(),
            true,
        ),
        (
            "laws",
            sw.laws.iter().map(|l| l.name().to_string()).collect(),
            true,
        ),
        (
            "compensate",
            sw.compensate.iter().map(|c| c.name().to_string()).collect(),
            true,
        ),
        (
            "tde_delay_samples",
            sw.tde_delay_samples.iter().map(u32::to_string).collect(),
            true,
        ),
        (
            "transport_delay_samples",
            sw.transport_delay_samples
                .iter()
                .map(u32::to_string)
                .collect(),
            true,
        ),
        (
            "transport_delay_us",
            sw.transport_delay_us.iter().map(f64::to_string).collect(),
            false,
        ),
        (
            "compute_delay_us",
            sw.compute_delay_us.iter().map(u32::to_string).collect(),
            false,
        ),
        (
            "link_delay_us",
            sw.link_delay_us.iter().map(f64::to_string).collect(),
            false,
        ),
    ];
    for (k, values, required) in axes {
        if required && values.is_empty() {
            bail!("sweep key `{k}` = [] is out of range: at least one value");
        }
        if let Some(v) = repeated(&values) {
            bail!("sweep key `{k}` lists {v} twice: each value at most once");
        }
    }
    check_compensate(sw)
}

/// Every law runs in some variant (`pid` only uncompensated), and no compensated law on the link
/// axis: a link point's delay is the emulated link's, not its config's, so a compensated law
/// would predict over none and its in-process twin over the measured arrival.
fn check_compensate(sw: &SweepFile) -> Result<()> {
    let listed = || {
        let v: Vec<&str> = sw.compensate.iter().map(|c| c.name()).collect();
        format!("[\"{}\"]", v.join("\", \""))
    };
    if let Some(law) = sw.laws.iter().find(|l| !l.uses_tde())
        && !sw.compensate.is_empty()
        && !sw.compensate.contains(&Compensation::None)
    {
        bail!(
            "sweep key `compensate` = {} leaves `{law}` nothing to run: it has no TDE model to predict with and runs only uncompensated; add \"none\" to `compensate` or take `{law}` off `laws`",
            listed()
        );
    }
    if sw.compensate.contains(&Compensation::Predict) && !sw.link_delay_us.is_empty() {
        bail!(
            "sweep key `compensate` = {} with `link_delay_us`: a link point's delay is the emulated link's, which a compensated law is not told; run the link axis in a sweep of its own, uncompensated",
            listed()
        );
    }
    Ok(())
}

/// Most emulated delay or jitter a link point may ask for, µs: the `[link]` bound.
pub use deltaloop_config::MAX_LINK_DELAY_US as MAX_LINK_US;

/// The link axis's keys: delays and jitter 0..=[`MAX_LINK_US`] µs, loss a fraction, and jitter
/// or loss only with delays to apply them to.
fn check_link(sw: &SweepFile) -> Result<()> {
    let in_range = |v: f64| v.is_finite() && (0.0..=MAX_LINK_US).contains(&v);
    if let Some(&v) = sw.link_delay_us.iter().find(|v| !in_range(**v)) {
        bail!(
            "sweep key `link_delay_us` lists {}: each value 0 <= us <= {MAX_LINK_US} µs (emulated delay, each direction)",
            cfgfile::show_num(v)
        );
    }
    // The bridge and the point's folder name take the delay in whole ns: two values that round
    // to the same ns are one point (regression: 0.0001 and 0.0002 shared a folder).
    let ns = |v: f64| (v * 1e3).round() as u64;
    for (i, &a) in sw.link_delay_us.iter().enumerate() {
        // (The same value twice is said by the axes' own check.)
        let same_ns = |&&b: &&f64| ns(b) == ns(a) && b.to_bits() != a.to_bits();
        if let Some(&b) = sw.link_delay_us[..i].iter().find(same_ns) {
            bail!(
                "sweep key `link_delay_us` lists {} and {}: the same delay in whole ns ({} ns); each value at most once",
                cfgfile::show_num(b),
                cfgfile::show_num(a),
                ns(a)
            );
        }
    }
    if !in_range(sw.link_jitter_us) {
        bail!(
            "sweep key `link_jitter_us` = {} is out of range: 0 <= us <= {MAX_LINK_US} µs",
            cfgfile::show_num(sw.link_jitter_us)
        );
    }
    if !(sw.link_loss.is_finite() && (0.0..=1.0).contains(&sw.link_loss)) {
        bail!(
            "sweep key `link_loss` = {} is out of range: 0 <= loss <= 1 (a fraction of datagrams)",
            cfgfile::show_num(sw.link_loss)
        );
    }
    if sw.link_delay_us.is_empty() {
        for (k, v) in [
            ("link_jitter_us", sw.link_jitter_us),
            ("link_loss", sw.link_loss),
        ] {
            if v != 0.0 {
                bail!(
                    "sweep key `{k}` = {} applies to the link points: list their delays in `link_delay_us` (or leave it out)",
                    cfgfile::show_num(v)
                );
            }
        }
    }
    Ok(())
}

/// Reads the sweep's base scenario. Its text is never echoed: `base` may name any file (say
/// `/etc/passwd`), so a parse error says only where it is.
fn load_base(path: &Path) -> Result<RunConfig> {
    RunConfig::from_file(path).map_err(|e| match e {
        ConfigError::Parse { position, .. } => anyhow::anyhow!(
            "sweep key `base`: {} is not a valid scenario config (parse error{}; `deltaloop run` on it shows the message)",
            cfgfile::show_path(path),
            position
                .map(|(l, c)| format!(" at line {l}, column {c}"))
                .unwrap_or_default()
        ),
        e => anyhow::anyhow!("sweep key `base`: {e}"),
    })
}

/// Loads and checks a sweep file; returns it with the base config resolved. Like a scenario
/// file, the sweep file and its base are read only if they are regular files of at most
/// [`cfgfile::MAX_FILE_BYTES`].
pub fn load(path: &Path) -> Result<(SweepFile, RunConfig)> {
    load_with_base(path, None)
}

/// The base config a sweep reads: `base` when given, else the sweep file's `base` key, relative
/// to the sweep file's folder.
pub fn base_path(path: &Path, sw: &SweepFile, base: Option<&Path>) -> PathBuf {
    base.map_or_else(
        || path.parent().unwrap_or(Path::new(".")).join(&sw.base),
        Path::to_path_buf,
    )
}

/// [`load`], with the base read from `base` instead of the file's `base` key when given (a copy
/// shipped next to the sweep file; the key stays as written).
pub fn load_with_base(path: &Path, base: Option<&Path>) -> Result<(SweepFile, RunConfig)> {
    let shown = cfgfile::show_path(path);
    let text = cfgfile::read_text_file(path)
        .map_err(|reason| anyhow::anyhow!("cannot read sweep file {shown}: {reason}"))?;
    let sw: SweepFile = toml::from_str(&text).map_err(|e| {
        anyhow::anyhow!(
            "invalid sweep file {shown}: {}",
            cfgfile::toml_error_line(&text, &e)
        )
    })?;
    check(&sw)?;
    let base = load_base(&base_path(path, &sw, base))?;
    check_seeds(&sw, &base)?;
    Ok((sw, base))
}

/// The seeds of the repeats, `sensor.seed` … + repeats − 1, must not wrap past 2⁶⁴ − 1
/// (regression: `sensor.seed = 18446744073709551615` with 3 repeats was reported as "seeds
/// 18446744073709551615 to 1").
fn check_seeds(sw: &SweepFile, base: &RunConfig) -> Result<()> {
    let last = u64::MAX - u64::from(sw.repeats - 1);
    if base.sensor.seed > last {
        bail!(
            "base key `sensor.seed` = {} with repeats = {}: the repeats' seeds would wrap past {}; allowed 0..={last}",
            base.sensor.seed,
            sw.repeats,
            u64::MAX
        );
    }
    Ok(())
}

/// The sweep's points in the canonical expansion order (scenario, preset, law, then ℓ × d, then
/// the side axes), once its own keys pass [`check`].
pub(super) fn jobs(sw: &SweepFile) -> Result<Vec<Job>> {
    check(sw)?;
    let mut v = Vec::new();
    for &scenario in &sw.scenarios {
        for &preset in &sw.presets {
            for LawVariant { law, compensate } in variants(sw) {
                for &ell in &sw.tde_delay_samples {
                    for &d in &sw.transport_delay_samples {
                        v.push(Job {
                            scenario,
                            preset,
                            law,
                            compensate,
                            ell,
                            d,
                            kind: PointKind::Grid,
                        });
                    }
                }
                // The side axes run at the first ℓ and d; D = 0 is the grid point itself.
                let side = |kind| Job {
                    scenario,
                    preset,
                    law,
                    compensate,
                    ell: sw.tde_delay_samples[0],
                    d: sw.transport_delay_samples[0],
                    kind,
                };
                for &us in sw.transport_delay_us.iter().filter(|&&us| us > 0.0) {
                    v.push(side(PointKind::SubTick { us }));
                }
                for &us in &sw.compute_delay_us {
                    v.push(side(PointKind::Compute { us }));
                }
                for &delay_us in &sw.link_delay_us {
                    v.push(side(PointKind::Link(Link {
                        delay_us,
                        jitter_us: sw.link_jitter_us,
                        loss: sw.link_loss,
                    })));
                }
            }
        }
    }
    Ok(v)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A sweep of exactly [`MAX_POINTS`] points is counted whole (one more is refused:
    /// `regression_sweep_points_are_counted_and_capped_before_expanding`).
    #[test]
    fn a_sweep_at_the_cap_is_counted_whole() {
        let list = |n: usize| {
            let v: Vec<String> = (0..n).map(|i| i.to_string()).collect();
            format!("[{}]", v.join(","))
        };
        let sw: SweepFile = toml::from_str(&format!(
            "name = \"c\"\nbase = \"base.toml\"\nscenarios = [\"s1\", \"s2\"]\npresets = [\"matched\"]\nlaws = [\"tdc\"]\ntde_delay_samples = {}\ntransport_delay_samples = {}\n",
            list(250),
            list(200)
        ))
        .unwrap();
        assert_eq!(point_count(&sw).unwrap(), MAX_POINTS);
    }

    /// `compensate = ["none", "predict"]` runs each TDE law twice and `pid` once, counted as
    /// expanded; an empty or repeated list is refused, and so are a `pid` with nothing to run
    /// and compensated laws on the link axis.
    #[test]
    fn the_compensate_axis_runs_each_tde_law_both_ways_and_pid_once() {
        let sweep = |comp: &str| {
            toml::from_str::<SweepFile>(&format!(
                "name = \"c\"\nbase = \"b.toml\"\nscenarios = [\"s2\"]\npresets = [\"matched\"]\nlaws = [\"tdc\", \"pid\"]\n{comp}tde_delay_samples = [1]\ntransport_delay_samples = [0, 1]\ntransport_delay_us = [0, 45]\n"
            ))
            .unwrap()
        };
        let sw = sweep("compensate = [\"none\", \"predict\"]\n");
        let names: Vec<String> = variants(&sw).iter().map(|v| v.to_string()).collect();
        assert_eq!(names, ["tdc", "tdc+pred", "pid"]);
        let j = jobs(&sw).unwrap();
        assert_eq!(j.len() as u64, point_count(&sw).unwrap());
        assert_eq!(j.len(), 3 * 3);
        assert_eq!(
            j.iter()
                .filter(|j| j.compensate == Compensation::Predict)
                .count(),
            3
        );
        // Without the key, as before: one variant per law.
        assert_eq!(variants(&sweep("")).len(), 2);
        let e = check(&sweep("compensate = [\"predict\"]\n"))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("`compensate` = [\"predict\"] leaves `pid` nothing to run")
                && !e.contains('\n'),
            "{e}"
        );
        let mut link = sweep("compensate = [\"none\", \"predict\"]\n");
        link.link_delay_us = vec![25.0];
        let e = check(&link).unwrap_err().to_string();
        assert!(e.contains("with `link_delay_us`"), "{e}");
        for (comp, says) in [
            ("compensate = []\n", "`compensate` = [] is out of range"),
            (
                "compensate = [\"predict\", \"predict\"]\n",
                "`compensate` lists predict twice",
            ),
        ] {
            let e = check(&sweep(comp)).unwrap_err().to_string();
            assert!(e.contains(says), "{e}");
        }
    }

    /// Regression: `sensor.seed = 2⁶⁴ − 1` with 3 repeats ran seeds that wrapped to 0 and 1, and
    /// the report said "seeds 18446744073709551615 to 1". The sweep is refused in one line.
    #[test]
    fn regression_repeat_seeds_that_would_wrap_are_refused() {
        let sw: SweepFile = toml::from_str(
            "name = \"s\"\nbase = \"b.toml\"\nscenarios = [\"s1\"]\npresets = [\"matched\"]\nlaws = [\"tdc\"]\ntde_delay_samples = [1]\ntransport_delay_samples = [0]\nrepeats = 3\n",
        )
        .unwrap();
        let mut base = RunConfig::from_toml_str("[scenario]\npath = \"s1\"\n", None).unwrap();
        base.sensor.seed = u64::MAX;
        let e = check_seeds(&sw, &base).unwrap_err().to_string();
        assert!(
            e.contains("`sensor.seed` = 18446744073709551615 with repeats = 3")
                && e.contains("allowed 0..=18446744073709551613")
                && !e.contains('\n'),
            "{e}"
        );
        base.sensor.seed = u64::MAX - 2;
        check_seeds(&sw, &base).unwrap();
    }
}
