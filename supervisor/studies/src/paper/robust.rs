//! The paper's robustness table: with a realistic sensor (quantisation + noise) the super-twisting
//! laws' RMS against `tde-is`'s over many sensor-noise seeds, as a paired ratio with its t-based
//! 95 % confidence interval; and the same ratio measured in realtime on this machine, over
//! several runs. A single run's ratio can sit on either side of 1 by chance; these say whether
//! the ranking holds.

use super::CONFIGS;
use anyhow::{Context, Result};
use deltaloop_config::PathKind;
use deltaloop_config::{Law, LoopMode, Preset, RunConfig, SensorSection};
use deltaloop_runner::lawrun::Keep;
use deltaloop_runner::{Ran, inproc};
use deltaloop_study::Study;
use deltaloop_study::record::RunStatus;
use deltaloop_study::record::stats::{self, Interval, RatioInterval};
use serde::Serialize;
use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::Path;

/// The laws the robustness table compares: `tde-is` (the denominator), the paper's explicit
/// super-twisting law and the implicit one (the paper's own tables run [`super::LAWS`]).
pub const ROBUST_LAWS: [Law; 3] = [Law::TdeIs, Law::TdcIsSta, Law::TdcIsIsta];

/// Sensor-noise seeds by default (`deltaloop paper --seeds`).
pub const SEEDS: u32 = 20;

/// Realtime runs per scenario by default (`deltaloop paper --realtime-runs`).
pub const REALTIME_RUNS: u32 = 5;

/// The robustness runs' sensor: a 22-bit absolute joint encoder (4 194 304 counts per revolution,
/// a 1.5 µrad quantum), white noise of σ = 0.2 µrad on q before quantisation and σ = 1 mrad/s
/// on the measured q̇ — the order of an industrial servo drive's position loop. The seed is set
/// per run.
pub fn sensor(seed: u64) -> SensorSection {
    SensorSection {
        encoder_counts_per_rev: 4_194_304,
        q_noise_std_rad: 2e-7,
        qd_noise_std_rad_s: 1e-3,
        seed,
        ..SensorSection::default()
    }
}

/// One scenario under one preset in one mode, over its seeds (or runs).
#[derive(Debug, Serialize)]
pub struct Row {
    pub scenario: PathKind,
    pub preset: Preset,
    pub mode: LoopMode,
    /// Seeds (inproc) or runs (realtime) in which every law ended `ok`: the ratios' samples.
    pub runs: usize,
    /// Seeds or runs left out because some law did not end `ok`.
    pub left_out: usize,
    /// Max-joint RMS tracking error per law over the runs, rad.
    pub rms_rad: BTreeMap<Law, Interval>,
    /// tdc-is-sta / tde-is, paired run by run (same seed).
    pub sta_over_is: Option<RatioInterval>,
    /// tdc-is-ista / tde-is, paired run by run.
    pub ista_over_is: Option<RatioInterval>,
    /// The two ratios' p-values after [`stats::CORRECTION`] (None: not a test of the table).
    pub sta_holm_p: Option<f64>,
    pub ista_holm_p: Option<f64>,
    /// Realtime: deadline misses over all runs and laws.
    pub misses: Option<u64>,
    /// Realtime: the median over runs and laws of the round trip's median, µs.
    pub round_trip_p50_us: Option<f64>,
}

/// The robustness table as `summary.json` holds it.
#[derive(Debug, Serialize)]
pub struct Robustness {
    pub sensor: SensorSection,
    pub seeds: u32,
    pub realtime_runs: u32,
    /// The interval of the RMS columns and of the ratios.
    pub interval: &'static str,
    pub ratio_interval: &'static str,
    /// The multiple-comparison correction of the verdicts.
    pub correction: &'static str,
    pub rows: Vec<Row>,
    /// Wall time of the in-process part and of the realtime part, s.
    pub inproc_s: f64,
    pub realtime_s: f64,
}

/// One law's run: whether it ended `ok`, max-joint RMS (rad) and, in realtime, round-trip p50
/// (µs) and deadline misses.
#[derive(Clone, Copy, Debug)]
struct Got {
    ok: bool,
    rms: f64,
    rtt_p50_us: Option<f64>,
    misses: Option<u64>,
}

/// One run of every law of [`ROBUST_LAWS`].
type Sample = Vec<Got>;

fn maxj(v: [f64; 3]) -> f64 {
    v.into_iter().fold(0.0, f64::max)
}

/// The config of one robustness run: a shipped scenario with the sensor above, the three laws,
/// no trace.
fn config(text: &str, name: &str, seed: u64) -> Result<RunConfig> {
    let mut cfg = RunConfig::from_toml_str(text, Some(Path::new(&format!("{name}.toml"))))?;
    cfg.sensor = sensor(seed);
    cfg.controller.laws = ROBUST_LAWS.to_vec();
    cfg.record.trace = false;
    cfg.validate()?;
    Ok(cfg)
}

/// Every law in-process with sensor seed `seed`.
fn inproc_sample(text: &str, name: &str, seed: u64) -> Result<Sample> {
    let study = Study::new(config(text, name, seed)?).context("reference")?;
    ROBUST_LAWS
        .iter()
        .map(|&law| {
            let r = inproc::run_law(&study, law, &Keep::default())?;
            Ok(Got {
                ok: r.metrics.status == RunStatus::Ok,
                rms: maxj(r.metrics.rms_rad),
                rtt_p50_us: None,
                misses: None,
            })
        })
        .collect()
}

/// Every law in realtime with sensor seed `seed`, its pair's files in `dir`.
fn realtime_sample(text: &str, name: &str, seed: u64, dir: &Path) -> Result<Sample> {
    let study = Study::new(config(text, name, seed)?).context("reference")?;
    std::fs::create_dir_all(dir)?;
    deltaloop_report::write_text(&dir.join("config.toml"), &study.config.to_toml_string())?;
    ROBUST_LAWS
        .iter()
        .map(|&law| {
            let ran = deltaloop_runner::run_law(
                &study,
                law,
                LoopMode::Realtime,
                dir,
                &Keep::default(),
                None,
            )?;
            let Ran::Process(p) = ran else {
                unreachable!("a realtime run is a process run")
            };
            let ok = p.run.metrics.status == RunStatus::Ok;
            let t = p.timing.summary();
            Ok(Got {
                ok,
                rms: maxj(p.run.metrics.rms_rad),
                rtt_p50_us: (t.round_trip.count > 0).then_some(t.round_trip.p50_us),
                misses: Some(t.deadline_misses),
            })
        })
        .collect()
}

/// A row out of its samples.
fn row(scenario: PathKind, preset: Preset, mode: LoopMode, samples: &[Sample]) -> Row {
    let complete: Vec<&Sample> = samples.iter().filter(|s| s.iter().all(|g| g.ok)).collect();
    let col = |i: usize| complete.iter().map(|s| s[i].rms).collect::<Vec<f64>>();
    let ratio = |i: usize| {
        RatioInterval::of(
            &complete
                .iter()
                .map(|s| s[i].rms / s[0].rms)
                .collect::<Vec<f64>>(),
        )
    };
    let mut rtts: Vec<f64> = complete
        .iter()
        .flat_map(|s| s.iter().filter_map(|x| x.rtt_p50_us))
        .collect();
    rtts.sort_by(f64::total_cmp);
    Row {
        scenario,
        preset,
        mode,
        runs: complete.len(),
        left_out: samples.len() - complete.len(),
        rms_rad: ROBUST_LAWS
            .iter()
            .enumerate()
            .filter_map(|(i, &l)| Some((l, Interval::of(&col(i))?)))
            .collect(),
        sta_over_is: ratio(1),
        ista_over_is: ratio(2),
        sta_holm_p: None,
        ista_holm_p: None,
        round_trip_p50_us: rtts.get(rtts.len() / 2).copied(),
        // Every run's misses, also those of the runs left out (often the reason they were).
        misses: samples
            .iter()
            .flatten()
            .filter_map(|g| g.misses)
            .reduce(|a, b| a + b),
    }
}

/// Runs the table: every shipped case × `seeds` seeds in-process (on every core), then the
/// matched preset's scenarios `realtime_runs` times each in realtime (their pairs' files under
/// `out/robustness/`).
pub fn run(out: &Path, seeds: u32, realtime_runs: u32, progress: bool) -> Result<Robustness> {
    let t0 = std::time::Instant::now();
    let jobs: Vec<(usize, u64)> = (0..CONFIGS.len())
        .flat_map(|c| (1..=u64::from(seeds)).map(move |s| (c, s)))
        .collect();
    let bar = deltaloop_report::progress_bar(jobs.len(), progress);
    bar.set_message("robustness: sensor-noise seeds in-process");
    let threads = std::thread::available_parallelism().map_or(1, |n| n.get());
    let results = deltaloop_runner::pool::map(&jobs, threads, |&(c, seed)| {
        let (_, name, text) = CONFIGS[c];
        let r = inproc_sample(text, name, seed);
        bar.inc(1);
        r
    });
    bar.finish_and_clear();
    let mut rows = Vec::new();
    // The jobs run case by case, `seeds` each: so do their results.
    let mut results = results.into_iter();
    for (preset, name, text) in CONFIGS.iter() {
        let samples = results
            .by_ref()
            .take(seeds as usize)
            .collect::<Result<Vec<Sample>>>()?;
        let scenario = config(text, name, 1)?.scenario.path;
        rows.push(row(scenario, *preset, LoopMode::Inproc, &samples));
    }
    let inproc_s = t0.elapsed().as_secs_f64();
    let t1 = std::time::Instant::now();
    if realtime_runs > 0 {
        let cases: Vec<_> = CONFIGS.iter().filter(|c| c.0 == Preset::Matched).collect();
        let bar = deltaloop_report::progress_bar(cases.len() * realtime_runs as usize, progress);
        for (preset, name, text) in cases {
            let mut samples = Vec::new();
            for i in 1..=u64::from(realtime_runs) {
                bar.set_message(format!("robustness: {name} in realtime, run {i}"));
                let dir = out.join("robustness").join(format!("{name}-run{i}"));
                samples.push(realtime_sample(text, name, i, &dir)?);
                bar.inc(1);
                if deltaloop_runner::signals::interrupted() {
                    break;
                }
            }
            let scenario = config(text, name, 1)?.scenario.path;
            rows.push(row(scenario, *preset, LoopMode::Realtime, &samples));
        }
        bar.finish_and_clear();
    }
    correct(&mut rows);
    Ok(Robustness {
        sensor: sensor(1),
        seeds,
        realtime_runs,
        interval: stats::CI_METHOD,
        ratio_interval: stats::RATIO_CI_METHOD,
        correction: stats::CORRECTION,
        rows,
        inproc_s,
        realtime_s: t1.elapsed().as_secs_f64(),
    })
}

/// Corrects every ratio of the table with [`MIN_RUNS`] or more runs for their number (Holm).
fn correct(rows: &mut [Row]) {
    let tested = |r: &Option<RatioInterval>| {
        r.filter(|i| i.n >= MIN_RUNS)
            .map_or(f64::NAN, |i| i.p_value)
    };
    let p: Vec<f64> = rows
        .iter()
        .flat_map(|r| [tested(&r.sta_over_is), tested(&r.ista_over_is)])
        .collect();
    let adjusted = stats::holm(&p);
    let finite = |x: f64| x.is_finite().then_some(x);
    for (row, pair) in rows.iter_mut().zip(adjusted.chunks(2)) {
        row.sta_holm_p = finite(pair[0]);
        row.ista_holm_p = finite(pair[1]);
    }
}

/// Fewest runs a verdict is drawn from: below it, t₀.₉₇₅ is so large (12.7 at n = 2) and the
/// normality of a mean of so few so doubtful that the interval decides nothing.
pub const MIN_RUNS: usize = 5;

/// The verdict a ratio allows after the correction: `holm_p`, its corrected p-value, below 0.05
/// (the uncorrected one is below 0.05 exactly when its 95 % interval excludes 1).
pub fn verdict(r: Option<&RatioInterval>, holm_p: Option<f64>) -> &'static str {
    match (r, holm_p) {
        (Some(i), _) if i.n < MIN_RUNS => "too few runs (fewer than 5)",
        (Some(i), Some(p)) if p < 0.05 && i.geo_mean < 1.0 => "lower: holds",
        (Some(i), Some(p)) if p < 0.05 && i.geo_mean > 1.0 => "higher: holds",
        (Some(i), Some(_)) if i.below(1.0) || i.above(1.0) => {
            "not decided after the correction (the raw interval excludes 1)"
        }
        (Some(_), _) => "not decided (the interval holds 1)",
        (None, _) => "no runs",
    }
}

/// A p-value for the table: 2 significant digits, `< 1e-6` below.
fn show_p(p: Option<f64>) -> String {
    match p {
        Some(p) if p < 1e-6 => "< 1e-6".into(),
        Some(p) if p < 0.01 => format!("{p:.1e}"),
        Some(p) => format!("{p:.2}"),
        None => "–".into(),
    }
}

/// The report section.
pub fn markdown(o: &mut String, r: &Robustness) {
    let se = &r.sensor;
    let _ = writeln!(
        o,
        "## Robustness: does the ranking hold over sensor-noise seeds and realtime runs?\n\n\
         A single run's ratio can land on either side of 1 by chance. Here the sensor is realistic: \
         a {}-count joint encoder (quantum {:.2} µrad), noise σ_q = {:e} rad before quantisation, \
         σ_q̇ = {:e} rad/s on the measured velocity (`sensor` in `summary.json`). Each case ran {} seed(s) (1..={}) in-process; \
         the ratios are paired seed by seed (max-joint RMS of the law over that of `tde-is`, same \
         seed), as the {}. Each ratio is also a two-sided one-sample t-test of the mean log ratio \
         against 0 (p), and the verdicts take {}: \"holds\" when the corrected p (Holm p) is below 0.05, on the side \
         of 1 the geometric mean is on.\n",
        se.encoder_counts_per_rev,
        std::f64::consts::TAU / f64::from(se.encoder_counts_per_rev) * 1e6,
        se.q_noise_std_rad,
        se.qd_noise_std_rad_s,
        r.seeds,
        r.seeds,
        r.ratio_interval,
        r.correction
    );
    let _ = writeln!(
        o,
        "| scenario | preset | mode | runs | `tde-is` RMS (rad) | `tdc-is-sta` / `tde-is` | p | Holm p | verdict | `tdc-is-ista` / `tde-is` | p | Holm p | verdict |\n|---|---|---|---|---|---|---|---|---|---|---|---|---|"
    );
    for row in &r.rows {
        let show = |i: Option<&RatioInterval>| i.map_or("–".into(), |i| i.show());
        let _ = writeln!(
            o,
            "| {} | {} | {}{} | {}{} | {} | {} | {} | {} | {} | {} | {} | {} | {} |",
            row.scenario.name().to_uppercase(),
            row.preset,
            row.mode,
            match (row.round_trip_p50_us, row.misses) {
                (Some(p), Some(m)) => format!(" (round trip p50 {p:.0} µs, {m} misses)"),
                (Some(p), None) => format!(" (round trip p50 {p:.0} µs)"),
                _ => String::new(),
            },
            row.runs,
            if row.left_out > 0 {
                format!(" ({} left out: a law did not end ok)", row.left_out)
            } else {
                String::new()
            },
            row.rms_rad
                .get(&Law::TdeIs)
                .map_or("–".into(), |i| format!("{:.3e}", i.mean)),
            show(row.sta_over_is.as_ref()),
            show_p(row.sta_over_is.map(|i| i.p_value).filter(|p| p.is_finite())),
            show_p(row.sta_holm_p),
            verdict(row.sta_over_is.as_ref(), row.sta_holm_p),
            show(row.ista_over_is.as_ref()),
            show_p(
                row.ista_over_is
                    .map(|i| i.p_value)
                    .filter(|p| p.is_finite())
            ),
            show_p(row.ista_holm_p),
            verdict(row.ista_over_is.as_ref(), row.ista_holm_p),
        );
    }
    let _ = writeln!(
        o,
        "\nRatios: geometric mean [95 % CI]; a verdict needs {MIN_RUNS} runs or more. {} In-process part {:.1} s, realtime part {:.1} s.\n",
        if r.realtime_runs > 0 {
            format!(
                "Realtime rows: the matched preset, {} run(s) each, one after the other on this machine; each run's three laws ran with the same seed, so a ratio pairs the same noise under different measured timing; the misses are those of every run, also those left out.",
                r.realtime_runs
            )
        } else {
            "No realtime runs (`--realtime-runs 0`).".to_string()
        },
        r.inproc_s,
        r.realtime_s
    );
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Ratios are paired run by run and a run in which any law did not end ok is left out.
    #[test]
    fn ratios_pair_seeds_and_leave_out_incomplete_runs() {
        let g = |rms, rtt| Got {
            ok: true,
            rms,
            rtt_p50_us: rtt,
            misses: Some(1),
        };
        let s = |a: f64, b: f64, c: f64| vec![g(a, None), g(b, Some(10.0)), g(c, None)];
        let samples = vec![
            s(2.0, 1.0, 3.0),
            s(4.0, 4.0, 4.0),
            vec![
                g(1.0, None),
                Got {
                    ok: false,
                    ..g(1.0, None)
                },
                g(1.0, None),
            ],
        ];
        let r = row(PathKind::S1, Preset::Matched, LoopMode::Inproc, &samples);
        assert_eq!((r.runs, r.left_out), (2, 1));
        let sta = r.sta_over_is.unwrap();
        assert_eq!(sta.n, 2);
        assert!((sta.geo_mean - 0.5f64.sqrt()).abs() < 1e-15); // 0.5 and 1.0
        assert!((r.ista_over_is.unwrap().geo_mean - 1.5f64.sqrt()).abs() < 1e-15); // 1.5 and 1.0
        assert_eq!(r.rms_rad[&Law::TdeIs].mean, 3.0);
        assert_eq!(r.round_trip_p50_us, Some(10.0));
        assert_eq!(
            r.misses,
            Some(9),
            "every run's misses, the left-out one's too"
        );
        let v = |xs: &[f64]| {
            let r = RatioInterval::of(xs);
            verdict(r.as_ref(), r.map(|i| i.p_value))
        };
        assert_eq!(v(&[0.5, 0.6, 0.55, 0.52, 0.58]), "lower: holds");
        assert_eq!(v(&[1.5, 1.6, 1.55, 1.52, 1.58]), "higher: holds");
        assert_eq!(
            v(&[0.5, 1.6, 0.7, 1.2, 0.9]),
            "not decided (the interval holds 1)"
        );
        assert_eq!(v(&[0.5, 0.6, 0.55, 0.52]), "too few runs (fewer than 5)");
        assert_eq!(v(&[]), "no runs");
    }

    /// The table's verdicts take Holm's correction over its tests: a ratio whose raw interval
    /// just excludes 1 is not decided among many tests, and one far from 1 still holds; rows
    /// with too few runs are not tests (they widen nobody's correction).
    #[test]
    fn verdicts_are_corrected_for_the_number_of_ratios() {
        let mut rows = Vec::new();
        let near = [0.9, 1.0, 0.92, 0.98, 0.91]; // raw p ≈ 0.03
        let far = [0.5, 0.52, 0.49, 0.51, 0.5];
        for (sta, ista) in [
            (&near[..], &near[..]),
            (&near[..], &far[..]),
            (&far[..4], &near[..]),
        ] {
            rows.push(Row {
                sta_over_is: RatioInterval::of(sta),
                ista_over_is: RatioInterval::of(ista),
                ..row(PathKind::S1, Preset::Matched, LoopMode::Inproc, &[])
            });
        }
        let raw = rows[0].sta_over_is.unwrap();
        assert!(raw.p_value < 0.05 && raw.below(1.0), "{raw:?}");
        correct(&mut rows);
        // Five tests (the four-run ratio is not one): the far one first (×5), then the four equal
        // near ones, the first of them ×4, and the later ones keep that running maximum.
        let p = rows[0].sta_holm_p.unwrap();
        assert!(p > 0.05 && (p - 4.0 * raw.p_value).abs() < 1e-12, "{p}");
        assert_eq!(rows[0].ista_holm_p, Some(p));
        assert_eq!(
            verdict(rows[0].sta_over_is.as_ref(), rows[0].sta_holm_p),
            "not decided after the correction (the raw interval excludes 1)"
        );
        let far_p = rows[1].ista_over_is.unwrap().p_value;
        assert!((rows[1].ista_holm_p.unwrap() - 5.0 * far_p).abs() < 1e-15);
        assert_eq!(
            verdict(rows[1].ista_over_is.as_ref(), rows[1].ista_holm_p),
            "lower: holds"
        );
        assert_eq!(rows[2].sta_holm_p, None);
        assert_eq!(
            verdict(rows[2].sta_over_is.as_ref(), rows[2].sta_holm_p),
            "too few runs (fewer than 5)"
        );
    }
}
