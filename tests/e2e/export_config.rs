//! `export` reads a run folder by column name and checks it as replay does; a config may ask for
//! a bounded number of ticks, checked at once (not tick by tick), by every command that reads one.

use crate::common;

use common::{deltaloop, finish_within, one_line_error, spawn};
use std::path::{Path, PathBuf};
use std::sync::OnceLock;
use std::time::Duration;

/// An in-process run of S2 (one law, 668 rows), made once; each test exports a copy.
fn base_run() -> &'static Path {
    static RUN: OnceLock<(tempfile::TempDir, PathBuf)> = OnceLock::new();
    let (_, out) = RUN.get_or_init(|| {
        let tmp = tempfile::tempdir().unwrap();
        let cfg = tmp.path().join("s2.toml");
        std::fs::write(
            &cfg,
            "name = \"s2\"\n[scenario]\npath = \"s2\"\n[controller]\nlaws = [\"tdc\"]\n",
        )
        .unwrap();
        let out = tmp.path().join("run");
        common::run(cfg.to_str().unwrap(), "inproc", &out, &[]);
        (tmp, out)
    });
    out
}

/// A copy of the base run whose trace.csv is `edit` of its lines; also the trace's path.
fn edited_run(edit: impl FnOnce(&mut Vec<String>)) -> (tempfile::TempDir, PathBuf, PathBuf) {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("run");
    std::fs::create_dir(&dir).unwrap();
    for name in ["config.toml", "summary.json", "trace.csv"] {
        std::fs::copy(base_run().join(name), dir.join(name)).unwrap();
    }
    let trace = dir.join("trace.csv");
    let text = std::fs::read_to_string(&trace).unwrap();
    let mut lines: Vec<String> = text.lines().map(str::to_string).collect();
    edit(&mut lines);
    std::fs::write(&trace, lines.join("\n") + "\n").unwrap();
    (tmp, dir, trace)
}

/// `export DIR --mcap`: refused in one line, and no run.mcap written.
fn export_refused(dir: &Path) -> String {
    let o = deltaloop(&["export", dir.to_str().unwrap(), "--mcap"]);
    let err = one_line_error(&o);
    assert!(!dir.join("run.mcap").exists(), "{err}");
    err
}

/// Sets field `column` of line `line` (0: the header) to `value`.
fn set(lines: &mut [String], line: usize, column: &str, value: &str) {
    let at = lines[0].split(',').position(|c| c == column).unwrap();
    let mut f: Vec<&str> = lines[line].split(',').collect();
    f[at] = value;
    lines[line] = f.join(",");
}

#[test]
fn regression_export_took_columns_by_position_a_missing_column_is_refused() {
    let (_tmp, dir, trace) = edited_run(|lines| {
        let at = lines[0]
            .split(',')
            .position(|c| c == "tau_applied_2")
            .unwrap();
        for l in lines.iter_mut() {
            let mut f: Vec<&str> = l.split(',').collect();
            f.remove(at);
            *l = f.join(",");
        }
    });
    let err = export_refused(&dir);
    assert!(
        err.contains(&format!("{} line 1", trace.display())) && err.contains("`tau_applied_2`"),
        "{err}"
    );
}

#[test]
fn regression_export_accepted_a_reply_of_maybe() {
    let (_tmp, dir, trace) = edited_run(|lines| set(lines, 5, "reply", "maybe"));
    let err = export_refused(&dir);
    assert!(
        err.contains(&format!("{} line 6", trace.display()))
            && err.contains("reply")
            && err.contains("maybe")
            && err.contains("applied, late, skipped, missed or unknown"),
        "{err}"
    );
}

#[test]
fn regression_export_accepted_a_duplicated_tick() {
    let (_tmp, dir, trace) = edited_run(|lines| {
        let again = lines[10].clone();
        lines.insert(11, again);
    });
    let err = export_refused(&dir);
    assert!(
        err.contains(&format!("{} line 12", trace.display()))
            && err.contains("column k = \"9\"")
            && err.contains("after tick 9"),
        "{err}"
    );
}

#[test]
fn regression_export_accepted_a_timing_cell_x() {
    let (_tmp, dir, _) = edited_run(|_| {});
    let timing = dir.join("tdc.timing.csv");
    let header = deltaloop_timing::TIMING_COLUMNS.join(",");
    std::fs::write(
        &timing,
        format!("{header}\n0,1000,1000,1000,1000,1000,1000,0,0,0,0,0,\n1,x,,,,,,,,,,,\n"),
    )
    .unwrap();
    let err = export_refused(&dir);
    assert!(
        err.contains(&format!("{} line 3", timing.display()))
            && err.contains("deadline_ns")
            && err.contains("\"x\""),
        "{err}"
    );
}

/// 30 custom segments of an hour each at the shortest period: 10.8 G ticks (about 3 KB).
fn hostile_config() -> String {
    let seg =
        "{ from = [0.25, 0, -0.43], to = [-0.25, 0, -0.43], apex_m = 0.12, duration_s = 3600.0 }";
    let segs = vec![seg; 30].join(",\n  ");
    format!(
        "name = \"long\"\n[scenario]\npath = \"custom\"\nsegments = [\n  {segs}\n]\n[loop]\nts_s = 1e-5\ntorque_budget_us = 5\n"
    )
}

/// What the refusal names: the first segment past the bound, its value and the bound.
fn assert_names_the_bound(err: &str) {
    assert!(
        err.contains("scenario.segments[0].duration_s` = 3600") && err.contains("300000000 ticks"),
        "{err}"
    );
}

#[test]
fn regression_a_3kb_config_of_hour_segments_hung_for_hours() {
    let tmp = tempfile::tempdir().unwrap();
    let cfg = tmp.path().join("long.toml");
    std::fs::write(&cfg, hostile_config()).unwrap();
    let out = tmp.path().join("run");
    let o = finish_within(
        spawn(&[
            "run",
            cfg.to_str().unwrap(),
            "--mode",
            "inproc",
            "--out",
            out.to_str().unwrap(),
        ]),
        Duration::from_secs(1),
        "run of the hostile config",
    );
    assert_names_the_bound(&one_line_error(&o));
}

#[test]
fn regression_export_replay_whatif_hung_on_a_run_folder_of_that_config() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("run");
    std::fs::create_dir(&dir).unwrap();
    let cfg = dir.join("config.toml");
    std::fs::write(&cfg, hostile_config()).unwrap();
    std::fs::write(dir.join("summary.json"), "{}").unwrap();
    std::fs::copy(base_run().join("trace.csv"), dir.join("trace.csv")).unwrap();
    let (d, c) = (dir.to_str().unwrap(), cfg.to_str().unwrap());
    let whatif_out = tmp.path().join("w");
    let replay_out = tmp.path().join("r");
    for args in [
        vec!["export", d, "--mcap"],
        vec!["replay", d, "--out", replay_out.to_str().unwrap()],
        vec![
            "whatif",
            c,
            "--latency",
            d,
            "--out",
            whatif_out.to_str().unwrap(),
        ],
    ] {
        let o = finish_within(spawn(&args), Duration::from_secs(1), args[0]);
        assert_names_the_bound(&one_line_error(&o));
    }
}
