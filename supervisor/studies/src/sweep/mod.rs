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

mod compensation;
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
    use deltaloop_study::record::RunStatus;
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
        // The cap itself passes (its count: schema.rs's tests).
        let path = d.0.join("sweep.toml");
        std::fs::write(&path, file(250, 200, 0)).unwrap();
        load(&path).unwrap();
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
            compensate: deltaloop_config::Compensation::None,
            ell: 2,
            d: 1,
            kind: PointKind::Compute { us: 200 },
        };
        assert_eq!(rt.to_string(), "s2/paper/tde-is ℓ=2 d=1 c=200us (realtime)");
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
        assert_eq!(
            (rows[0].law, rows[0].status),
            (Law::Pid.into(), RunStatus::Ok)
        );
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
