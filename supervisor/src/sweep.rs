//! `deltaloop sweep <sweep.toml>`: a grid of runs (scenarios × presets × laws × ℓ × d, plus a
//! realtime compute-delay axis), each through the same code as `deltaloop run`. Writes
//! `sweep.csv` (row by row, so an interrupted sweep keeps what finished), `sweep.json`,
//! `report.md` and plots of RMS error, TDE error and δ_N against each delay.

use crate::inproc;
use crate::metrics::{self, LawMetrics};
use crate::plot::{self, Panel, Series};
use crate::procs;
use crate::study::Study;
use anyhow::{Context, Result, bail};
use deltaloop_config::config::PathKind;
use deltaloop_config::{Law, LoopMode, Preset, RunConfig};
use serde::{Deserialize, Serialize};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::sync::atomic::{AtomicUsize, Ordering};

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
    pub tde_delay_samples: Vec<u32>,
    pub transport_delay_samples: Vec<u32>,
    /// Realtime axis: each value runs every law × scenario × preset in realtime mode at the first
    /// ℓ and d above. Empty: no realtime runs.
    #[serde(default)]
    pub compute_delay_us: Vec<u32>,
}

/// One grid point's result: a row of `sweep.csv`.
#[derive(Debug, Clone, Serialize)]
pub struct Row {
    pub scenario: String,
    pub preset: String,
    pub law: Law,
    pub mode: LoopMode,
    pub tde_delay_samples: u32,
    pub transport_delay_samples: u32,
    pub compute_delay_us: u32,
    /// ok | diverged | error
    pub status: String,
    pub diverged_at_tick: Option<u64>,
    pub reason: String,
    /// Max over joints of the RMS joint error, rad.
    pub rms_rad: f64,
    pub max_abs_err_rad: f64,
    pub task_rms_mm: f64,
    /// Max over joints of the TDE error RMS, rad/s².
    pub tde_err_rms: f64,
    /// Max over joints of δ_N max and of its 99.9th percentile, rad/s³.
    pub delta_n_max: f64,
    pub delta_n_p999: f64,
    pub k2_required: f64,
    pub eq43_holds: bool,
    pub hf_torque_share: f64,
    pub clamp_count: u64,
    pub deadline_misses: Option<u64>,
    pub round_trip_p999_us: Option<f64>,
}

#[derive(Debug, Clone)]
struct Job {
    scenario: PathKind,
    preset: Preset,
    law: Law,
    ell: u32,
    d: u32,
    compute_us: u32,
    realtime: bool,
}

/// A metric read off a row.
type Metric = fn(&Row) -> f64;

fn maxj(v: [f64; 3]) -> f64 {
    v.into_iter().fold(0.0, f64::max)
}

fn row(
    job: &Job,
    mode: LoopMode,
    m: Option<&LawMetrics>,
    err: Option<String>,
    timing: Option<&crate::timing::TimingSummary>,
) -> Row {
    let (status, reason) = match (m, &err) {
        (_, Some(e)) => ("error".to_string(), e.clone()),
        (Some(m), None) if !m.completed => (
            "diverged".into(),
            m.diverged_reason.clone().unwrap_or_default(),
        ),
        _ => ("ok".into(), String::new()),
    };
    let nan = f64::NAN;
    Row {
        scenario: format!("{:?}", job.scenario).to_lowercase(),
        preset: job.preset.name().into(),
        law: job.law,
        mode,
        tde_delay_samples: job.ell,
        transport_delay_samples: job.d,
        compute_delay_us: job.compute_us,
        status,
        diverged_at_tick: m.and_then(|m| m.diverged_at_tick),
        reason,
        rms_rad: m.map_or(nan, |m| maxj(m.rms_rad)),
        max_abs_err_rad: m.map_or(nan, |m| maxj(m.max_abs_err_rad)),
        task_rms_mm: m.map_or(nan, |m| m.task_rms_mm),
        tde_err_rms: m.and_then(|m| m.tde_err_rms).map_or(nan, maxj),
        delta_n_max: m.and_then(|m| m.delta_n_max).map_or(nan, maxj),
        delta_n_p999: m.and_then(|m| m.delta_n_p999).map_or(nan, maxj),
        k2_required: m.and_then(|m| m.k2_required).unwrap_or(nan),
        eq43_holds: m.and_then(|m| m.eq43_holds).unwrap_or(false),
        hf_torque_share: m.map_or(nan, |m| maxj(m.hf_torque_share)),
        clamp_count: m.map_or(0, |m| m.clamp_count),
        deadline_misses: timing.map(|t| t.deadline_misses),
        round_trip_p999_us: timing.map(|t| t.round_trip.p999_us),
    }
}

/// The config of one grid point: the base with the axes applied, validated.
fn point_config(base: &RunConfig, job: &Job) -> Result<RunConfig> {
    let mut c = base.clone();
    c.name = format!(
        "{:?}-{}-{}-l{}-d{}-c{}",
        job.scenario,
        job.preset.name(),
        job.law,
        job.ell,
        job.d,
        job.compute_us
    )
    .to_lowercase();
    c.scenario.path = job.scenario;
    c.scenario.segments.clear();
    // The preset axis sets the constants that differ between presets (M̄, φ); the base's other
    // constants (gains) stay as the base resolved them.
    c.controller.preset = job.preset;
    let p = deltaloop_config::ControllerParams::preset(job.preset);
    c.controller.m_bar = Some(p.m_bar);
    c.controller.phi = Some(p.phi);
    c.controller.laws = vec![job.law];
    c.controller.tde_delay_samples = job.ell;
    c.controller.compute_delay_us = job.compute_us;
    c.plant.transport_delay_samples = job.d;
    c.validate()?;
    Ok(c)
}

fn run_job(base: &RunConfig, job: &Job, mode: LoopMode, dir: &Path) -> Row {
    let attempt = || -> Result<(LawMetrics, Option<crate::timing::TimingSummary>)> {
        let cfg = point_config(base, job)?;
        let study = Study::new(cfg).context("reference")?;
        let mode = if job.realtime {
            LoopMode::Realtime
        } else {
            mode
        };
        let (run, timing) = if mode.is_process() {
            let pdir = dir.join("points").join(&study.config.name);
            std::fs::create_dir_all(&pdir)?;
            std::fs::write(pdir.join("config.toml"), study.config.to_toml_string())?;
            let r = procs::run_law(&study, job.law, mode, &pdir)?;
            (r.run, Some(r.timing.summary()))
        } else {
            (inproc::run_law(&study, job.law), None)
        };
        Ok((
            metrics::compute(&run, &study.reference, &study.robot, &study.params),
            timing,
        ))
    };
    let mode = if job.realtime {
        LoopMode::Realtime
    } else {
        mode
    };
    match std::panic::catch_unwind(std::panic::AssertUnwindSafe(attempt)) {
        Ok(Ok((m, t))) => row(job, mode, Some(&m), None, t.as_ref()),
        Ok(Err(e)) => row(job, mode, None, Some(format!("{e:#}")), None),
        Err(p) => row(
            job,
            mode,
            None,
            Some(format!(
                "panic: {:?}",
                p.downcast_ref::<String>()
                    .cloned()
                    .or(p.downcast_ref::<&str>().map(|s| s.to_string()))
            )),
            None,
        ),
    }
}

/// Loads and checks a sweep file; returns it with the base config resolved.
pub fn load(path: &Path) -> Result<(SweepFile, RunConfig)> {
    let text = std::fs::read_to_string(path)
        .with_context(|| format!("cannot read sweep file {}", path.display()))?;
    let sw: SweepFile = toml::from_str(&text).map_err(|e| {
        anyhow::anyhow!(
            "invalid sweep file {}: {}",
            path.display(),
            e.to_string().trim_end()
        )
    })?;
    if sw.mode == LoopMode::Realtime {
        bail!(
            "sweep key `mode` = \"{}\" is out of range: inproc or lockstep (the compute_delay_us axis runs in realtime by itself)",
            sw.mode
        );
    }
    for (k, empty) in [
        ("scenarios", sw.scenarios.is_empty()),
        ("presets", sw.presets.is_empty()),
        ("laws", sw.laws.is_empty()),
        ("tde_delay_samples", sw.tde_delay_samples.is_empty()),
        (
            "transport_delay_samples",
            sw.transport_delay_samples.is_empty(),
        ),
    ] {
        if empty {
            bail!("sweep key `{k}` = [] is out of range: at least one value");
        }
    }
    let base_path = path.parent().unwrap_or(Path::new(".")).join(&sw.base);
    let base = RunConfig::from_file(&base_path)?;
    Ok((sw, base))
}

fn jobs(sw: &SweepFile) -> Vec<Job> {
    let mut v = Vec::new();
    for &scenario in &sw.scenarios {
        for &preset in &sw.presets {
            for &law in &sw.laws {
                for &ell in &sw.tde_delay_samples {
                    for &d in &sw.transport_delay_samples {
                        v.push(Job {
                            scenario,
                            preset,
                            law,
                            ell,
                            d,
                            compute_us: 0,
                            realtime: false,
                        });
                    }
                }
                for &c in &sw.compute_delay_us {
                    v.push(Job {
                        scenario,
                        preset,
                        law,
                        ell: sw.tde_delay_samples[0],
                        d: sw.transport_delay_samples[0],
                        compute_us: c,
                        realtime: true,
                    });
                }
            }
        }
    }
    v
}

/// Loads the sweep file at `path` and runs it into `out`; returns the rows (in grid order).
/// A caller that has already loaded the file (e.g. to name the output folder) passes the result
/// to [`run_loaded`] instead, so the file is read and parsed once.
pub fn run(path: &Path, out: &Path, progress: bool) -> Result<Vec<Row>> {
    let (sw, base) = load(path)?;
    run_loaded(&sw, &base, path, out, progress)
}

/// Runs a sweep loaded by [`load`] from `path` (named in the report) into `out`; returns the
/// rows (in grid order).
pub fn run_loaded(
    sw: &SweepFile,
    base: &RunConfig,
    path: &Path,
    out: &Path,
    progress: bool,
) -> Result<Vec<Row>> {
    // Every point must be a valid config before anything runs.
    let all = jobs(sw);
    for j in &all {
        point_config(base, j).with_context(|| format!("sweep point {j:?}"))?;
    }
    std::fs::create_dir_all(out).with_context(|| format!("cannot create {}", out.display()))?;
    std::fs::write(out.join("sweep.toml"), toml::to_string_pretty(sw)?)?;
    std::fs::write(out.join("base.toml"), base.to_toml_string())?;
    let rows = run_grid(sw, base, &all, out, progress)?;
    std::fs::write(out.join("sweep.json"), serde_json::to_string_pretty(&rows)?)?;
    let figures = plots(sw, &rows, out)?;
    let mut md = report(sw, &rows, &figures, path);
    if crate::signals::interrupted() {
        md.insert_str(0, &format!("> **Interrupted** (Ctrl-C / SIGTERM) after {} of {} runs: the tables hold the finished ones.\n\n", rows.len(), all.len()));
        std::fs::write(out.join("report.md"), md)?;
        return Err(anyhow::Error::new(crate::run::Interrupted(
            out.to_path_buf(),
        )));
    }
    std::fs::write(out.join("report.md"), md)?;
    Ok(rows)
}

/// Runs every job, appending each result to `sweep.csv` as it finishes: deterministic inproc
/// points in parallel (one worker per CPU), process runs one at a time. Stops starting jobs on
/// Ctrl-C / SIGTERM. Returns the finished rows in grid order.
fn run_grid(
    sw: &SweepFile,
    base: &RunConfig,
    all: &[Job],
    out: &Path,
    progress: bool,
) -> Result<Vec<Row>> {
    let bar = crate::output::progress_bar(all.len(), progress);
    let writer = Mutex::new(
        csv::Writer::from_path(out.join("sweep.csv")).context("cannot create sweep.csv")?,
    );
    let results: Mutex<Vec<Option<Row>>> = Mutex::new(vec![None; all.len()]);
    let record = |i: usize, r: Row| -> Result<()> {
        {
            let mut w = writer.lock().expect("csv writer");
            w.serialize(&r)?;
            w.flush()?;
        }
        bar.set_message(format!(
            "{} {} {} l={} d={} c={}us: {}",
            r.scenario,
            r.preset,
            r.law,
            r.tde_delay_samples,
            r.transport_delay_samples,
            r.compute_delay_us,
            r.status
        ));
        bar.inc(1);
        results.lock().expect("results")[i] = Some(r);
        Ok(())
    };
    let (parallel, serial): (Vec<usize>, Vec<usize>) =
        (0..all.len()).partition(|&i| !all[i].realtime && sw.mode == LoopMode::Inproc);
    let next = AtomicUsize::new(0);
    let workers = std::thread::available_parallelism().map_or(1, |n| n.get());
    std::thread::scope(|s| -> Result<()> {
        let handles: Vec<_> = (0..workers)
            .map(|_| {
                s.spawn(|| -> Result<()> {
                    loop {
                        if crate::signals::interrupted() {
                            return Ok(());
                        }
                        let n = next.fetch_add(1, Ordering::Relaxed);
                        let Some(&i) = parallel.get(n) else {
                            return Ok(());
                        };
                        record(i, run_job(base, &all[i], sw.mode, out))?;
                    }
                })
            })
            .collect();
        for h in handles {
            h.join()
                .map_err(|_| anyhow::anyhow!("sweep worker panicked"))??;
        }
        Ok(())
    })?;
    for i in serial {
        if crate::signals::interrupted() {
            break;
        }
        record(i, run_job(base, &all[i], sw.mode, out))?;
    }
    bar.finish_with_message("done");
    Ok(results
        .into_inner()
        .expect("results")
        .into_iter()
        .flatten()
        .collect())
}

/// (file stem, x axis, metric) of every figure written.
fn plots(sw: &SweepFile, rows: &[Row], out: &Path) -> Result<Vec<(String, String)>> {
    let mut written = Vec::new();
    let metrics: [(&str, &str, Metric); 3] = [
        ("rms", "RMS joint error, max over joints (rad)", |r| {
            r.rms_rad
        }),
        ("tde_err", "TDE error RMS, max over joints (rad/s²)", |r| {
            r.tde_err_rms
        }),
        ("delta_n", "δ_N max, max over joints (rad/s³)", |r| {
            r.delta_n_max
        }),
    ];
    let axes: [(&str, &str, bool); 3] = [
        ("tde_delay", "TDE delay ℓ (ticks)", true),
        ("transport_delay", "transport delay d (ticks)", false),
        ("compute_delay", "controller compute delay (µs)", false),
    ];
    for (axis, x_label, log_x) in axes {
        let x_of = |r: &Row| -> f64 {
            match axis {
                "tde_delay" => f64::from(r.tde_delay_samples),
                "transport_delay" => f64::from(r.transport_delay_samples),
                _ => f64::from(r.compute_delay_us),
            }
        };
        // Hold the other axes at their first value.
        let on_axis = |r: &Row| -> bool {
            let (l0, d0) = (sw.tde_delay_samples[0], sw.transport_delay_samples[0]);
            match axis {
                "tde_delay" => r.mode != LoopMode::Realtime && r.transport_delay_samples == d0,
                "transport_delay" => r.mode != LoopMode::Realtime && r.tde_delay_samples == l0,
                _ => r.mode == LoopMode::Realtime,
            }
        };
        let values: Vec<f64> = rows.iter().filter(|r| on_axis(r)).map(x_of).collect();
        let distinct = {
            let mut v = values.clone();
            v.sort_by(f64::total_cmp);
            v.dedup();
            v.len()
        };
        if distinct < 2 {
            continue;
        }
        for (mname, y_label, get) in metrics {
            let mut panels = Vec::new();
            for &sc in &sw.scenarios {
                for &pr in &sw.presets {
                    let scn = format!("{sc:?}").to_lowercase();
                    let series = sw
                        .laws
                        .iter()
                        .map(|law| Series {
                            name: law.name().to_string(),
                            color: plot::law_color(law.name()),
                            points: rows
                                .iter()
                                .filter(|r| {
                                    on_axis(r)
                                        && r.scenario == scn
                                        && r.preset == pr.name()
                                        && r.law == *law
                                        && r.status == "ok"
                                })
                                .map(|r| (x_of(r), get(r)))
                                .collect(),
                        })
                        .collect();
                    panels.push(Panel {
                        title: format!("{} — preset {}", scn.to_uppercase(), pr.name()),
                        x_label: x_label.to_string(),
                        y_label: y_label.to_string(),
                        log_x: log_x && values.iter().all(|&v| v > 0.0),
                        log_y: true,
                        series,
                    });
                }
            }
            let stem = format!("{mname}_vs_{axis}");
            plot::figure(
                &out.join(&stem),
                &format!("{} vs {}", y_label, x_label),
                &panels,
                sw.presets.len(),
            )?;
            written.push((stem, format!("{y_label} vs {x_label}")));
        }
    }
    Ok(written)
}

fn cell(r: Option<&Row>, get: Metric) -> String {
    match r {
        None => "–".into(),
        Some(r) if r.status == "ok" => format!("{:.2e}", get(r)),
        Some(r) if r.status == "diverged" => format!("div@{}", r.diverged_at_tick.unwrap_or(0)),
        Some(_) => "error".into(),
    }
}

/// One markdown table: a row per law, a column per value of one delay axis.
fn axis_table<'a>(
    s: &mut String,
    caption: &str,
    sym: &str,
    values: &[u32],
    laws: &[Law],
    find: impl Fn(Law, u32) -> Option<&'a Row>,
    get: Metric,
) {
    let _ = writeln!(s, "{caption}:\n");
    let _ = write!(s, "| law |");
    for v in values {
        let _ = write!(s, " {sym}={v} |");
    }
    let _ = writeln!(s, "\n|---|{}", "---|".repeat(values.len()));
    for &law in laws {
        let _ = write!(s, "| `{law}` |");
        for &v in values {
            let _ = write!(s, " {} |", cell(find(law, v), get));
        }
        let _ = writeln!(s);
    }
    let _ = writeln!(s);
}

fn report(sw: &SweepFile, rows: &[Row], figures: &[(String, String)], path: &Path) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "# Sweep `{}`\n\n{}\n\nProduced by: `deltaloop sweep {}`. {} runs; deterministic axes in `{}` mode.\n",
        sw.name,
        sw.description,
        path.display(),
        rows.len(),
        sw.mode
    );
    let div = rows.iter().filter(|r| r.status == "diverged").count();
    let err = rows.iter().filter(|r| r.status == "error").count();
    let _ = writeln!(
        s,
        "Diverged: {div}; errors: {err}. A run diverges at the first tick with |e| > 0.5 rad, a non-finite value, or the robot leaving its workspace; it is recorded there (`div@tick`), never crashes the sweep.\n"
    );
    let tables: [(&str, Metric); 2] = [
        ("RMS joint error, max over joints (rad)", |r| r.rms_rad),
        ("TDE error RMS, max over joints (rad/s²)", |r| {
            r.tde_err_rms
        }),
    ];
    for &sc in &sw.scenarios {
        let scn = format!("{sc:?}").to_lowercase();
        for &pr in &sw.presets {
            for (title, get) in tables {
                let _ = writeln!(
                    s,
                    "## {} — preset `{}`: {title}\n",
                    scn.to_uppercase(),
                    pr.name()
                );
                let (l0, d0) = (sw.tde_delay_samples[0], sw.transport_delay_samples[0]);
                let base = |r: &&Row| {
                    r.mode != LoopMode::Realtime && r.scenario == scn && r.preset == pr.name()
                };
                let by_ell = |law: Law, l: u32| {
                    rows.iter().filter(base).find(|r| {
                        r.law == law && r.tde_delay_samples == l && r.transport_delay_samples == d0
                    })
                };
                let by_d = |law: Law, d: u32| {
                    rows.iter().filter(base).find(|r| {
                        r.law == law && r.tde_delay_samples == l0 && r.transport_delay_samples == d
                    })
                };
                axis_table(
                    &mut s,
                    &format!("Against the TDE delay ℓ (transport delay d = {d0})"),
                    "ℓ",
                    &sw.tde_delay_samples,
                    &sw.laws,
                    by_ell,
                    get,
                );
                axis_table(
                    &mut s,
                    &format!("Against the transport delay d (ℓ = {l0})"),
                    "d",
                    &sw.transport_delay_samples,
                    &sw.laws,
                    by_d,
                    get,
                );
                let _ = writeln!(s);
            }
        }
    }
    if !sw.compute_delay_us.is_empty() {
        let _ = writeln!(
            s,
            "## Controller compute delay (realtime)\n\n| scenario | preset | law | compute delay (µs) | status | RMS (rad) | misses | round trip p99.9 (µs) |\n|---|---|---|---|---|---|---|---|"
        );
        for r in rows.iter().filter(|r| r.mode == LoopMode::Realtime) {
            let _ = writeln!(
                s,
                "| {} | {} | `{}` | {} | {} | {:.2e} | {} | {:.1} |",
                r.scenario,
                r.preset,
                r.law,
                r.compute_delay_us,
                r.status,
                r.rms_rad,
                r.deadline_misses.unwrap_or(0),
                r.round_trip_p999_us.unwrap_or(f64::NAN)
            );
        }
        let _ = writeln!(s);
    }
    let _ = writeln!(s, "## Figures\n");
    for (stem, title) in figures {
        let _ = writeln!(s, "### {title}\n\n![{title}]({stem}.png)\n");
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The file is read once: what `load` returned is what runs, even if the file is gone.
    #[test]
    fn run_loaded_runs_what_it_is_given_without_rereading_the_file() {
        let dir = std::env::temp_dir().join(format!("deltaloop-sweep-once-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::write(dir.join("base.toml"), "[scenario]\npath = \"s1\"\n").unwrap();
        let path = dir.join("sweep.toml");
        std::fs::write(
            &path,
            "name = \"once\"\nbase = \"base.toml\"\nscenarios = [\"s1\"]\npresets = [\"matched\"]\n\
             laws = [\"tdc\"]\ntde_delay_samples = [1]\ntransport_delay_samples = [0]\n",
        )
        .unwrap();
        let (mut sw, base) = load(&path).unwrap();
        std::fs::remove_file(&path).unwrap();
        sw.laws = vec![Law::Pid];
        let rows = run_loaded(&sw, &base, &path, &dir.join("out"), false);
        let _ = std::fs::remove_dir_all(&dir);
        let rows = rows.unwrap();
        assert_eq!(rows.len(), 1);
        assert_eq!((rows[0].law, rows[0].status.as_str()), (Law::Pid, "ok"));
    }
}
