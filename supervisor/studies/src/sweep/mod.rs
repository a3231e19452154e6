//! `deltaloop sweep <sweep.toml>`: a grid of runs (scenarios × presets × laws × ℓ × d, plus a
//! realtime compute-delay axis), each through the same code as `deltaloop run`. Writes
//! `sweep.csv` (row by row, so an interrupted sweep keeps what finished), `sweep.json`,
//! `report.md` and plots of RMS error, TDE error and δ_N against each delay.
//!
//! A sweep is a [`plan::Plan`] (every point with a stable id); [`shard`] runs any subset of it
//! into a folder of its own, and [`merge`] turns shard folders into the sweep's outputs. The
//! one-machine sweep is the same path: plan, run every point into the output folder, merge it.

use anyhow::Result;
use deltaloop_config::RunConfig;
use std::path::Path;

pub mod merge;
pub mod plan;
mod plots;
mod point;
mod report;
mod schema;
pub mod shard;
pub mod tasks;

use plots::*;
pub use point::*;
use report::*;
pub use report::{LINK_MATCH_TOLERANCE, link_match, link_verdict};
pub use schema::*;

/// Loads the sweep file at `path` and runs it into `out`; returns the rows (in grid order).
/// A caller that has already loaded the file (e.g. to name the output folder) passes the result
/// to [`run_loaded`] instead, so the file is read and parsed once.
pub fn run(path: &Path, out: &Path, progress: bool) -> Result<Vec<Row>> {
    let (sw, base) = load(path)?;
    run_loaded(&sw, &base, path, out, progress)
}

/// Runs a sweep loaded by [`load`] from `path` (named in the report) into `out`; returns the
/// rows (in plan order). The same path as a cluster sweep: the plan, every point run into `out`
/// as one shard (`sweep.csv` grows row by row), then `out` merged into itself.
pub fn run_loaded(
    sw: &SweepFile,
    base: &RunConfig,
    path: &Path,
    out: &Path,
    progress: bool,
) -> Result<Vec<Row>> {
    // Every point must be a valid config before anything runs.
    let plan = plan::Plan::new(sw.clone(), base.clone())?;
    let all: Vec<usize> = (0..plan.points.len()).collect();
    plan.check_points(&all)?;
    let jobs = std::thread::available_parallelism().map_or(1, |n| n.get());
    let sweep_file = path.display().to_string();
    shard::run(&plan, &all, &sweep_file, out, jobs, progress)?;
    let interrupted = deltaloop_runner::signals::interrupted();
    let merged = merge::merge(
        &[out.to_path_buf()],
        out,
        merge::Options {
            allow_missing: interrupted,
            interrupted,
        },
    )?;
    if interrupted {
        return Err(anyhow::Error::new(deltaloop_runner::run::Interrupted(
            out.to_path_buf(),
        )));
    }
    Ok(merged.rows)
}

#[cfg(test)]
mod tests {
    use super::*;
    use deltaloop_config as cfgfile;
    use deltaloop_config::PathKind;
    use deltaloop_config::{Law, LoopMode, Preset};
    use deltaloop_runner::inproc;
    use deltaloop_runner::lawrun::Keep;
    use deltaloop_study::Study;
    use deltaloop_study::record::metrics::LawMetrics;
    use deltaloop_study::record::{Fault, FaultKind, Outcome, RunEnd, RunStatus};
    use std::path::PathBuf;

    /// A scratch folder with a valid base, removed on drop.
    struct Scratch(PathBuf);
    impl Drop for Scratch {
        fn drop(&mut self) {
            let _ = std::fs::remove_dir_all(&self.0);
        }
    }
    fn scratch(tag: &str) -> Scratch {
        let dir =
            std::env::temp_dir().join(format!("deltaloop-sweep-{tag}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::write(dir.join("base.toml"), "[scenario]\npath = \"s1\"\n").unwrap();
        Scratch(dir)
    }

    const AXES: &str = "scenarios = [\"s1\"]\npresets = [\"matched\"]\nlaws = [\"tdc\"]\ntde_delay_samples = [1]\ntransport_delay_samples = [0]\n";

    /// `load`'s error for a sweep file with `text` (the axes are appended when `axes`).
    fn load_err(dir: &Path, text: &str) -> String {
        let path = dir.join("sweep.toml");
        std::fs::write(&path, text).unwrap();
        let e = format!("{:#}", load(&path).unwrap_err());
        assert!(!e.contains(['\n', '\r']), "one line: {e}");
        e
    }

    /// Regression: no cap on a sweep's size (10⁸ points aborted on allocation). The count is
    /// the product of the axes, checked before expanding: the cap itself passes, one more
    /// point does not, and the line names every axis.
    #[test]
    fn regression_sweep_points_are_counted_and_capped_before_expanding() {
        let d = scratch("cap");
        let list = |n: usize| {
            let v: Vec<String> = (0..n).map(|i| i.to_string()).collect();
            format!("[{}]", v.join(","))
        };
        let file = |ells: usize, ds: usize, compute: usize| {
            format!(
                "name = \"c\"\nbase = \"base.toml\"\nscenarios = [\"s1\", \"s2\"]\npresets = [\"matched\"]\nlaws = [\"tdc\"]\ntde_delay_samples = {}\ntransport_delay_samples = {}\ncompute_delay_us = {}\n",
                list(ells),
                list(ds),
                list(compute)
            )
        };
        let sw: SweepFile = toml::from_str(&file(250, 200, 0)).unwrap();
        assert_eq!(point_count(&sw).unwrap(), MAX_POINTS);
        let e = load_err(&d.0, &file(250, 200, 1));
        assert_eq!(
            e,
            "the sweep has 100002 points: scenarios 2 × presets 1 × laws 1 × (tde_delay_samples 250 × transport_delay_samples 200 + transport_delay_us 0 + compute_delay_us 1), more than the 100000 a sweep may have: split it into several sweep files"
        );
    }

    #[test]
    fn regression_sweep_name_escapes_the_run_folder() {
        let d = scratch("name");
        for bad in [
            "../../../../tmp/victim",
            "a/b",
            "x\ny",
            "\u{200f}x",
            ".x",
            "-x",
            "",
        ] {
            let e = load_err(
                &d.0,
                &format!(
                    "name = {}\nbase = \"base.toml\"\n{AXES}",
                    toml::Value::from(bad)
                ),
            );
            assert_eq!(
                e,
                format!(
                    "sweep key `name` = {} is out of range: {}",
                    cfgfile::show_str(bad),
                    cfgfile::NAME_RULE
                )
            );
        }
    }

    #[test]
    fn regression_sweep_rejects_duplicate_axis_values() {
        let d = scratch("dup");
        let head = "name = \"dup\"\nbase = \"base.toml\"\n";
        for (key, list, shown) in [
            ("laws", "[\"tdc\", \"pid\", \"tdc\"]", "tdc"),
            ("scenarios", "[\"s1\", \"s1\"]", "s1"),
            ("presets", "[\"paper\", \"paper\"]", "paper"),
            ("tde_delay_samples", "[1, 2, 2]", "2"),
            ("transport_delay_samples", "[0, 0]", "0"),
            ("compute_delay_us", "[50, 50]", "50"),
        ] {
            let axes: String = AXES
                .lines()
                .filter(|l| !l.starts_with(&format!("{key} ")))
                .map(|l| format!("{l}\n"))
                .collect();
            let e = load_err(&d.0, &format!("{head}{axes}{key} = {list}\n"));
            assert_eq!(
                e,
                format!("sweep key `{key}` lists {shown} twice: each value at most once")
            );
        }
    }

    #[test]
    fn regression_sweep_base_content_is_never_echoed() {
        let d = scratch("base");
        std::fs::write(d.0.join("secret.toml"), "password = \"hunter2\"\n").unwrap();
        std::fs::write(d.0.join("syntax.toml"), "[scenario]\nhunter2 hunter2\n").unwrap();
        for (base, at) in [
            ("/etc/passwd", Some("line 1, column")),
            ("secret.toml", Some("line 1, column 1")),
            ("syntax.toml", Some("line 2, column 9")),
        ] {
            if !Path::new(base).is_absolute() || Path::new(base).is_file() {
                let e = load_err(&d.0, &format!("name = \"b\"\nbase = {base:?}\n{AXES}"));
                assert!(
                    e.starts_with("sweep key `base`: ")
                        && e.contains("is not a valid scenario config (parse error at ")
                        && at.is_none_or(|a| e.contains(a))
                        && !e.contains("root:")
                        && !e.contains("hunter2")
                        && !e.contains("password"),
                    "{e}"
                );
            }
        }
        // A valid TOML base that fails validation names the key and the value, as `run` would.
        std::fs::write(
            d.0.join("range.toml"),
            "[scenario]\npath = \"s1\"\nhold_s = -1.0\n",
        )
        .unwrap();
        let e = load_err(
            &d.0,
            &format!("name = \"b\"\nbase = \"range.toml\"\n{AXES}"),
        );
        assert!(
            e.starts_with("sweep key `base`: config key `scenario.hold_s` = -1"),
            "{e}"
        );
    }

    #[test]
    fn regression_sweep_and_base_files_must_be_small_regular_files() {
        let d = scratch("read");
        // The sweep file itself.
        for (path, kind) in [
            (d.0.clone(), "a directory"),
            (PathBuf::from("/dev/zero"), "a character device"),
        ] {
            let e = format!("{:#}", load(&path).unwrap_err());
            assert_eq!(
                e,
                format!(
                    "cannot read sweep file {}: it is {kind}, not a regular file",
                    path.display()
                )
            );
        }
        let big = d.0.join("big.toml");
        std::fs::write(&big, "#".repeat(cfgfile::MAX_FILE_BYTES as usize + 1)).unwrap();
        let e = format!("{:#}", load(&big).unwrap_err());
        assert!(e.contains("larger than 1 MiB"), "{e}");
        // Its base.
        for base in ["/dev/zero", "."] {
            let e = load_err(&d.0, &format!("name = \"b\"\nbase = {base:?}\n{AXES}"));
            assert!(
                e.starts_with("sweep key `base`: cannot read config file ")
                    && e.ends_with("not a regular file"),
                "{e}"
            );
        }
    }

    /// The link axis's keys: one line naming the key, the value and what is allowed; a link
    /// point runs realtime with its own id and folder, and refuses a base with a controller
    /// command of its own.
    #[test]
    fn link_axis_keys_are_checked_with_one_line() {
        let d = scratch("link");
        let head = format!("name = \"l\"\nbase = \"base.toml\"\n{AXES}");
        for (extra, says) in [
            (
                "link_delay_us = [50, -1]",
                "sweep key `link_delay_us` lists -1: each value 0 <= us <= 1000000 µs (emulated delay, each direction)",
            ),
            (
                "link_delay_us = [50, 50]",
                "sweep key `link_delay_us` lists 50 twice: each value at most once",
            ),
            (
                "link_delay_us = [0.0001, 0.0002]",
                "sweep key `link_delay_us` lists 0.0001 and 0.0002: the same delay in whole ns (0 ns); each value at most once",
            ),
            (
                "link_delay_us = [0, -0.0]",
                "sweep key `link_delay_us` lists 0 and -0: the same delay in whole ns (0 ns); each value at most once",
            ),
            (
                "link_delay_us = [50]\nlink_jitter_us = -2",
                "sweep key `link_jitter_us` = -2 is out of range: 0 <= us <= 1000000 µs",
            ),
            (
                "link_delay_us = [50]\nlink_loss = 1.5",
                "sweep key `link_loss` = 1.5 is out of range: 0 <= loss <= 1 (a fraction of datagrams)",
            ),
            (
                "link_loss = 0.01",
                "sweep key `link_loss` = 0.01 applies to the link points: list their delays in `link_delay_us` (or leave it out)",
            ),
        ] {
            assert_eq!(load_err(&d.0, &format!("{head}{extra}\n")), says);
        }
        let path = d.0.join("sweep.toml");
        std::fs::write(&path, format!("{head}link_delay_us = [0, 50]\n")).unwrap();
        let (sw, base) = load(&path).unwrap();
        let plan = plan::Plan::new(sw.clone(), base.clone()).unwrap();
        let labels: Vec<(String, LoopMode)> =
            plan.points.iter().map(|p| (p.label(), p.mode)).collect();
        assert_eq!(
            labels,
            [
                ("s1/matched/tdc ℓ=1 d=0".to_string(), LoopMode::Inproc),
                (
                    "s1/matched/tdc ℓ=1 d=0 link=0us (realtime, across the bridge)".into(),
                    LoopMode::Realtime
                ),
                (
                    "s1/matched/tdc ℓ=1 d=0 link=50us (realtime, across the bridge)".into(),
                    LoopMode::Realtime
                ),
            ]
        );
        let names: Vec<String> = plan
            .points
            .iter()
            .map(|p| point_config(&base, &p.job).unwrap().name)
            .collect();
        assert_eq!(names[1], "s1-matched-tdc-l1-d0-u0-c0-link0");
        assert_eq!(names[2], "s1-matched-tdc-l1-d0-u0-c0-link50000");
        // A sweep without the link keys serialises (and so hashes) as before they existed.
        let plain: SweepFile = toml::from_str(&head).unwrap();
        assert!(!toml::to_string(&plain).unwrap().contains("link"));
        let mut own = base.clone();
        own.controller.command = vec!["my-controller".into()];
        let e = format!("{:#}", point_config(&own, &plan.points[2].job).unwrap_err());
        assert!(
            e.starts_with("sweep key `link_delay_us` runs the built-in controller across the bridge: the base's controller.command = \"my-controller\"")
                && !e.contains('\n'),
            "{e}"
        );
    }

    #[test]
    fn regression_sweep_parse_error_is_one_line() {
        let d = scratch("parse");
        let e = load_err(
            &d.0,
            &format!("name = \"p\"\nbase = \"base.toml\"\n{AXES}lawz = 1\n"),
        );
        assert!(
            e.contains("invalid sweep file ")
                && e.contains(": unknown field `lawz`, expected one of")
                && e.ends_with(" at line 8, column 1"),
            "{e}"
        );
    }

    #[test]
    fn regression_sweep_point_error_has_no_debug_text() {
        let d = scratch("point");
        let path = d.0.join("sweep.toml");
        std::fs::write(
            &path,
            "name = \"pt\"\nbase = \"base.toml\"\nscenarios = [\"s1\"]\npresets = [\"matched\"]\nlaws = [\"tdc\"]\ntde_delay_samples = [0]\ntransport_delay_samples = [0]\n",
        )
        .unwrap();
        let (sw, base) = load(&path).unwrap();
        let e = format!(
            "{:#}",
            run_loaded(&sw, &base, &path, &d.0.join("out"), false).unwrap_err()
        );
        assert_eq!(
            e,
            "sweep point s1/matched/tdc ℓ=0 d=0: config key `controller.tde_delay_samples` = 0 is out of range: 1 <= tde_delay_samples <= 10000 ticks"
        );
        let rt = Job {
            scenario: PathKind::S2,
            preset: Preset::Paper,
            law: Law::TdeIs,
            ell: 2,
            d: 1,
            kind: PointKind::Compute { us: 200 },
        };
        assert_eq!(rt.to_string(), "s2/paper/tde-is ℓ=2 d=1 c=200us (realtime)");
    }

    /// S2, matched, `tdc`, ℓ = 1, d = 0, a realtime point at a 200 µs compute delay.
    fn s2_tdc_realtime_job() -> Job {
        Job {
            scenario: PathKind::S2,
            preset: Preset::Matched,
            law: Law::Tdc,
            ell: 1,
            d: 0,
            kind: PointKind::Compute { us: 200 },
        }
    }

    /// Repeats fold into one row: means over the `ok` repeats, the hand-computed standard
    /// deviation and t interval (rms 1, 2, 3 → mean 2, s = 1, t₀.₉₇₅,₂ = 4.302652729911275,
    /// half-width 4.302652729911275/√3 = 2.484137...), the first non-ok repeat's status named by
    /// its seed and left out, the largest counts.
    #[test]
    fn repeats_summarise_to_mean_std_and_t_interval() {
        let job = Job {
            kind: PointKind::Grid,
            ..s2_tdc_realtime_job()
        };
        let m = some_metrics();
        let mk = |rms: f64, seed: u64, clamps: u64| {
            let mut r = row(&job, 3e-4, LoopMode::Inproc, Some(&m), None, None);
            (r.rms_rad, r.seed, r.clamp_count) = (rms, seed, clamps);
            r
        };
        let mut bad = mk(f64::NAN, 13, 0);
        bad.status = RunStatus::Diverged;
        bad.reason = "|e| > 0.5 rad".into();
        let r = summarise(vec![
            mk(1.0, 10, 0),
            mk(2.0, 11, 5),
            mk(3.0, 12, 2),
            bad.clone(),
        ]);
        assert_eq!((r.repeats, r.repeats_ok, r.seed), (4, 3, 10));
        assert_eq!(r.status, RunStatus::Ok);
        assert_eq!(
            r.reason,
            "1 of 4 seeds did not end ok (left out of the means); seed 13 diverged: |e| > 0.5 rad"
        );
        // No repeat ok: the first repeat's status.
        let none = summarise(vec![bad.clone(), bad]);
        assert_eq!((none.status, none.repeats_ok), (RunStatus::Diverged, 0));
        assert_eq!((r.rms_rad, r.rms_rad_std), (2.0, 1.0));
        let half = 4.302652729911275 / 3f64.sqrt();
        assert!(
            (r.rms_rad_ci95_lo - (2.0 - half)).abs() < 1e-7,
            "{}",
            r.rms_rad_ci95_lo
        );
        assert!((r.rms_rad_ci95_hi - (2.0 + half)).abs() < 1e-7);
        assert_eq!(r.clamp_count, 5);
        // One repeat: the row as it was, no interval.
        let one = summarise(vec![mk(1.0, 10, 0)]);
        assert_eq!((one.repeats, one.rms_rad), (1, 1.0));
        assert!(one.rms_rad_std.is_nan() && one.rms_rad_ci95_lo.is_nan());
    }

    /// Regression: `repeats = 1` wrote the text `NaN` in the spread columns where the docs say
    /// a value that does not exist is an empty cell; an empty cell (or an old shard's `NaN`)
    /// reads back as no value.
    #[test]
    fn regression_a_single_repeat_leaves_its_spread_cells_empty_not_nan() {
        let job = Job {
            kind: PointKind::Grid,
            ..s2_tdc_realtime_job()
        };
        let one = summarise(vec![row(
            &job,
            3e-4,
            LoopMode::Inproc,
            Some(&some_metrics()),
            None,
            None,
        )]);
        let mut w = csv::Writer::from_writer(Vec::new());
        w.serialize(&one).unwrap();
        let text = String::from_utf8(w.into_inner().unwrap()).unwrap();
        assert!(!text.contains("NaN"), "{text}");
        let mut rd = csv::Reader::from_reader(text.as_bytes());
        let head = rd.headers().unwrap().clone();
        let rec = rd.records().next().unwrap().unwrap();
        for col in ["rms_rad_std", "rms_rad_ci95_lo", "latency_cost"] {
            let i = head.iter().position(|h| h == col).unwrap();
            assert_eq!(&rec[i], "", "{col} in {text}");
        }
        let i = head.iter().position(|h| h == "rms_rad").unwrap();
        assert!(rec[i].parse::<f64>().unwrap() > 0.0);
        // A shard of an older version wrote `NaN` there.
        let std = head.iter().position(|h| h == "rms_rad_std").unwrap();
        let old: csv::StringRecord = rec
            .iter()
            .enumerate()
            .map(|(k, c)| if k == std { "NaN" } else { c })
            .collect();
        let mut w = csv::Writer::from_writer(Vec::new());
        w.write_record(&head).unwrap();
        w.write_record(&old).unwrap();
        let old = String::from_utf8(w.into_inner().unwrap()).unwrap();
        for t in [text, old] {
            let back: Row = csv::Reader::from_reader(t.as_bytes())
                .deserialize()
                .next()
                .unwrap()
                .unwrap();
            assert!(back.rms_rad_std.is_nan() && back.rms_rad == one.rms_rad);
        }
    }

    /// Metrics of a real (short) run, to vary.
    fn some_metrics() -> LawMetrics {
        let cfg = RunConfig::from_toml_str(
            "[scenario]\npath = \"s2\"\n[controller]\nlaws = [\"tdc\"]\n",
            None,
        )
        .unwrap();
        let study = Study::new(cfg).unwrap();
        inproc::run_law(&study, Law::Tdc, &Keep::default())
            .unwrap()
            .metrics
    }

    /// `m` as if its run had ended with `outcome` and `fault`: the status fields as
    /// [`MetricsAcc::finish`](deltaloop_study::record::metrics::MetricsAcc::finish) sets them.
    fn ended(m: &LawMetrics, outcome: Outcome, fault: Option<Fault>) -> LawMetrics {
        let end = RunEnd {
            law: m.law,
            records: m.ticks + 1,
            lost_ticks: 0,
            first_lost: None,
            no_telemetry: u64::from(outcome == Outcome::LostData),
            first_no_telemetry: (outcome == Outcome::LostData).then_some(5),
            replies_lost: 0,
            first_reply_lost: None,
            duplicate_replies: 0,
            stamps_replaced: 0,
            outcome,
            fault,
        };
        LawMetrics {
            status: end.status(),
            reason: end.reason(),
            status_tick: end.status_tick(),
            fault_kind: end.fault.as_ref().map(|f| f.kind),
            completed: end.outcome == Outcome::Completed,
            diverged_at_tick: match end.outcome {
                Outcome::Diverged { tick, .. } => Some(tick),
                _ => None,
            },
            ..m.clone()
        }
    }

    #[test]
    fn regression_sweep_row_status_and_reason() {
        let job = s2_tdc_realtime_job();
        let ok = some_metrics();
        assert!(ok.completed);
        let rt = LoopMode::Realtime;
        let empty_timing = deltaloop_timing::Timing::default().summary();
        assert_eq!(empty_timing.round_trip.count, 0);

        let r = row(&job, 3e-4, rt, Some(&ok), None, Some(&empty_timing));
        assert_eq!((r.status, r.reason.as_str()), (RunStatus::Ok, ""));
        // No round-trip sample: no percentile, not 0.
        assert_eq!(r.round_trip_p999_us, None);
        let mut w = csv::Writer::from_writer(Vec::new());
        w.serialize(&r).unwrap();
        let text = String::from_utf8(w.into_inner().unwrap()).unwrap();
        let mut rd = csv::Reader::from_reader(text.as_bytes());
        let col = rd
            .headers()
            .unwrap()
            .iter()
            .position(|h| h == "round_trip_p999_us");
        let rec = rd.records().next().unwrap().unwrap();
        assert_eq!(&rec[col.unwrap()], "", "{text}");

        // A controller too slow for its deadlines: the plant stops on a fault. Not a divergence,
        // even if the error passed the bound while the torque was held.
        let slow = Fault {
            tick: 99,
            kind: FaultKind::ControllerSilent,
            cause: "no torque within the budget for 100 consecutive ticks".into(),
        };
        let m = ended(&ok, Outcome::Faulted, Some(slow.clone()));
        let r = row(&job, 3e-4, rt, Some(&m), None, Some(&empty_timing));
        assert_eq!(r.status, RunStatus::Fault);
        assert_eq!(m.fault_kind, Some(FaultKind::ControllerSilent));
        assert_eq!(r.reason, m.reason.clone().unwrap());
        let drifted = Outcome::Diverged {
            tick: 120,
            reason: "|e| > 0.5 rad".into(),
        };
        let m = ended(&ok, drifted, Some(slow.clone()));
        let r = row(&job, 3e-4, rt, Some(&m), None, None);
        assert_eq!((r.status, r.diverged_at_tick), (RunStatus::Fault, None));
        // A stop on request nobody here made is its own status.
        let stop = Fault {
            kind: FaultKind::Stopped,
            ..slow
        };
        let r = row(
            &job,
            3e-4,
            rt,
            Some(&ended(&ok, Outcome::Faulted, Some(stop))),
            None,
            None,
        );
        assert_eq!(r.status, RunStatus::Stopped);

        // Interrupted: marked, no metrics, not a result.
        let m = ended(&ok, Outcome::Interrupted { tick: 42 }, None);
        let r = row(&job, 3e-4, rt, Some(&m), None, Some(&empty_timing));
        assert_eq!(r.status, RunStatus::Interrupted);
        assert!(!r.is_result() && r.rms_rad.is_nan() && r.deadline_misses.is_none());

        // Diverged: the tick, and a reason even without a recorded one.
        let at7 = Outcome::Diverged {
            tick: 7,
            reason: String::new(),
        };
        let r = row(&job, 3e-4, rt, Some(&ended(&ok, at7, None)), None, None);
        assert_eq!(
            (r.status, r.diverged_at_tick),
            (RunStatus::Diverged, Some(7))
        );
        assert!(!r.reason.is_empty());
        let r = row(&job, 3e-4, rt, None, Some("boom".into()), None);
        assert_eq!((r.status, r.reason.as_str()), (RunStatus::Error, "boom"));
        let r = row(&job, 3e-4, rt, Some(&ok), Some("boom".into()), None);
        assert_eq!(r.status, RunStatus::Error);
        // The loop finished but the supervisor lost ticks: its own status, with the reason; the
        // csv says `lost_data`, and a row of an older sweep (`lost-data`) still reads.
        let m = ended(&ok, Outcome::LostData, None);
        let r = row(&job, 3e-4, rt, Some(&m), None, None);
        assert_eq!(r.status, RunStatus::LostData);
        assert!(!r.reason.is_empty());
        let mut w = csv::Writer::from_writer(Vec::new());
        w.serialize(&r).unwrap();
        let text = String::from_utf8(w.into_inner().unwrap()).unwrap();
        assert!(text.contains(",lost_data,"), "{text}");
        let old = text.replace(",lost_data,", ",lost-data,");
        let back: Row = csv::Reader::from_reader(old.as_bytes())
            .deserialize()
            .next()
            .unwrap()
            .unwrap();
        assert_eq!(back.status, RunStatus::LostData);

        // The report counts them apart and leaves the interrupted point out.
        let sw: SweepFile = toml::from_str(
            "name = \"r\"\nbase = \"b.toml\"\nscenarios = [\"s2\"]\npresets = [\"matched\"]\nlaws = [\"tdc\"]\ntde_delay_samples = [1]\ntransport_delay_samples = [0]\ncompute_delay_us = [200, 300]\n"
        )
        .unwrap();
        let too_slow = Fault {
            tick: 99,
            kind: FaultKind::ControllerSilent,
            cause: "too slow".into(),
        };
        let m = ended(&ok, Outcome::Faulted, Some(too_slow));
        let stopped = row(&job, 3e-4, rt, Some(&m), None, Some(&empty_timing));
        let m = ended(&ok, Outcome::Interrupted { tick: 3 }, None);
        let cut = row(
            &Job {
                kind: PointKind::Compute { us: 300 },
                ..job.clone()
            },
            3e-4,
            rt,
            Some(&m),
            None,
            None,
        );
        let md = report(&sw, &[stopped, cut], &[], Path::new("s.toml"));
        assert!(md.contains(" 1 points;"), "{md}");
        assert!(
            md.contains("Diverged: 0; stopped on a loop fault: 1; errors: 0."),
            "{md}"
        );
        assert!(
            md.contains("| fault |") && md.contains("fault at tick 99: too slow"),
            "{md}"
        );
        assert!(!md.contains("interrupted"), "{md}");
    }

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
        assert_eq!((rows[0].law, rows[0].status), (Law::Pid, RunStatus::Ok));
    }

    /// With an encoder in the base config the twins' one-ulp change stays inside a count: the
    /// sweep's report says so, as a run's does.
    #[test]
    fn a_sweep_says_when_an_encoder_hides_the_twins() {
        let dir = scratch("enc");
        let path = dir.0.join("sweep.toml");
        std::fs::write(
            dir.0.join("base.toml"),
            "[scenario]\npath = \"s2\"\n[sensor]\nencoder_counts_per_rev = 65536\n",
        )
        .unwrap();
        std::fs::write(
            &path,
            "name = \"enc\"\nbase = \"base.toml\"\nscenarios = [\"s2\"]\npresets = [\"matched\"]\n\
             laws = [\"tdc\"]\ntde_delay_samples = [1]\ntransport_delay_samples = [0]\n",
        )
        .unwrap();
        run(&path, &dir.0.join("out"), false).unwrap();
        let md = std::fs::read_to_string(dir.0.join("out/report.md")).unwrap();
        assert!(
            md.contains("**Round-off and the encoder**: the encoder quantises q"),
            "{md}"
        );
    }

    /// The sub-tick delay axis: its points sit on L_eff/Ts = ℓ + D/Ts, D = 300 µs is the grid's
    /// d = 1 bit for bit, and the latency budget is the largest D within 2× the zero-delay RMS
    /// (S2, matched, tdc: 7.2e-5 rad at 0, 9.5e-5 at 45 µs, 2.0e-4 at 300 µs).
    #[test]
    fn sub_tick_delay_axis_effective_delay_and_latency_budget() {
        let dir = scratch("us");
        let path = dir.0.join("sweep.toml");
        std::fs::write(
            dir.0.join("base.toml"),
            "[scenario]\npath = \"s2\"\n[plant]\nfriction = true\n",
        )
        .unwrap();
        std::fs::write(
            &path,
            "name = \"us\"\nbase = \"base.toml\"\nscenarios = [\"s2\"]\npresets = [\"matched\"]\n\
             laws = [\"tdc\"]\ntde_delay_samples = [1]\ntransport_delay_samples = [0, 1]\n\
             transport_delay_us = [0, 45, 300]\n",
        )
        .unwrap();
        let rows = run(&path, &dir.0.join("out"), false).unwrap();
        let leff: Vec<(u32, f64, f64)> = rows
            .iter()
            .map(|r| {
                (
                    r.transport_delay_samples,
                    r.transport_delay_us,
                    r.effective_delay_ticks,
                )
            })
            .collect();
        assert_eq!(
            leff,
            [
                (0, 0.0, 1.0),
                (1, 0.0, 2.0),
                (0, 45.0, 1.15),
                (0, 300.0, 2.0)
            ]
        );
        assert_eq!(rows[3].rms_rad, rows[1].rms_rad, "300 µs is d = 1");
        let md = std::fs::read_to_string(dir.0.join("out/report.md")).unwrap();
        assert!(
            md.contains("| s2 | matched | `tdc` | 7.21e-5 | 45 | 9.45e-5 |"),
            "{md}"
        );
        assert!(dir.0.join("out/rms_vs_effective_delay.png").is_file());
    }
}
