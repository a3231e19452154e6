//! End-to-end: hostile input to `deltaloop run` and `deltaloop sweep` (issue 10). Every refusal is
//! exit 1 with one line on stderr, quickly, and leaves nothing behind.

use crate::common;

use common::{finish_within, mkfifo, one_line_error, spawn};
use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::time::{Duration, Instant};

const BIN: &str = env!("CARGO_BIN_EXE_deltaloop");

/// `deltaloop <args>` run from `cwd`.
fn deltaloop_in(cwd: &Path, args: &[&str]) -> Output {
    Command::new(BIN)
        .args(args)
        .current_dir(cwd)
        .output()
        .expect("deltaloop runs")
}

/// Every entry under `dir`, recursively.
fn tree(dir: &Path) -> Vec<PathBuf> {
    let mut found = Vec::new();
    for e in std::fs::read_dir(dir).unwrap().flatten() {
        found.push(e.path());
        if e.file_type().unwrap().is_dir() {
            found.extend(tree(&e.path()));
        }
    }
    found
}

const BASE: &str = "[scenario]\npath = \"s1\"\n[controller]\nlaws = [\"tdc\"]\n";
const AXES: &str = "scenarios = [\"s1\"]\npresets = [\"matched\"]\nlaws = [\"tdc\"]\ntde_delay_samples = [1]\ntransport_delay_samples = [0]\n";

#[test]
fn regression_name_escapes_the_run_folder() {
    let tmp = tempfile::tempdir().unwrap();
    let cwd = tmp.path().join("a").join("work");
    std::fs::create_dir_all(&cwd).unwrap();
    // `runs/<stamp>-../../../escaped` would be `<cwd>/escaped`; deeper, outside the work folder.
    for name in [
        "../../../escaped",
        "../../../../escaped",
        "x/y",
        "x\ny",
        "\u{202e}x",
    ] {
        let text = format!("name = {}\n{BASE}", toml_str(name));
        std::fs::write(tmp.path().join("s.toml"), text).unwrap();
        let out = deltaloop_in(&cwd, &["run", "../../s.toml", "--mode", "inproc"]);
        let err = one_line_error(&out);
        assert!(
            err.contains("config key `name` = \"") && err.contains("A-Z a-z 0-9 . _ -"),
            "{err}"
        );
        // The sweep's name names a folder too.
        std::fs::write(tmp.path().join("base.toml"), BASE).unwrap();
        let text = format!("name = {}\nbase = \"base.toml\"\n{AXES}", toml_str(name));
        std::fs::write(tmp.path().join("sw.toml"), text).unwrap();
        let out = deltaloop_in(&cwd, &["sweep", "../../sw.toml"]);
        let err = one_line_error(&out);
        assert!(err.contains("sweep key `name` = \""), "{err}");
    }
    assert_eq!(tree(&cwd), Vec::<PathBuf>::new(), "nothing is created");
    let mut left = tree(tmp.path());
    left.sort();
    let expected: Vec<PathBuf> = ["a", "a/work", "base.toml", "s.toml", "sw.toml"]
        .iter()
        .map(|p| tmp.path().join(p))
        .collect();
    assert_eq!(left, expected, "nothing is created outside");
}

/// A TOML basic string holding `s` (control characters escaped the TOML way).
fn toml_str(s: &str) -> String {
    let mut out = String::from("\"");
    for c in s.chars() {
        match c {
            '"' => out.push_str("\\\""),
            '\\' => out.push_str("\\\\"),
            c if c.is_control() || !c.is_ascii() => out.push_str(&format!("\\u{:04X}", c as u32)),
            c => out.push(c),
        }
    }
    out.push('"');
    out
}

#[test]
fn regression_fifo_and_device_inputs_are_refused_not_read() {
    let tmp = tempfile::tempdir().unwrap();
    let fifo = tmp.path().join("cfg.toml");
    mkfifo(&fifo);
    let f = fifo.to_str().unwrap();
    // A FIFO with no writer would block the reader forever: refused before opening.
    let out = finish_within(
        spawn(&["run", f, "--mode", "inproc"]),
        Duration::from_secs(2),
        "run on a FIFO",
    );
    let err = one_line_error(&out);
    assert!(
        err.contains(f) && err.contains("it is a FIFO (named pipe), not a regular file"),
        "{err}"
    );
    let out = finish_within(
        spawn(&["sweep", f]),
        Duration::from_secs(2),
        "sweep on a FIFO",
    );
    let err = one_line_error(&out);
    assert!(
        err.contains("cannot read sweep file") && err.contains("FIFO"),
        "{err}"
    );
    // The sweep's base too.
    let sweep = tmp.path().join("sw.toml");
    std::fs::write(&sweep, format!("name = \"f\"\nbase = \"cfg.toml\"\n{AXES}")).unwrap();
    let out = finish_within(
        spawn(&["sweep", sweep.to_str().unwrap()]),
        Duration::from_secs(2),
        "sweep with a FIFO base",
    );
    let err = one_line_error(&out);
    assert!(
        err.contains("sweep key `base`") && err.contains("FIFO"),
        "{err}"
    );
    // /dev/zero never ends: refused, not read until memory runs out.
    let out = finish_within(
        spawn(&["run", "/dev/zero", "--mode", "inproc"]),
        Duration::from_secs(2),
        "run on /dev/zero",
    );
    let err = one_line_error(&out);
    assert!(err.contains("/dev/zero: it is a character device"), "{err}");
    // A file beyond the cap is refused with the cap named.
    let big = tmp.path().join("big.toml");
    std::fs::write(&big, format!("{BASE}{}", "#".repeat(2 << 20))).unwrap();
    let out = deltaloop_in(tmp.path(), &["run", "big.toml", "--mode", "inproc"]);
    let err = one_line_error(&out);
    assert!(err.contains("larger than 1 MiB"), "{err}");
}

#[test]
fn regression_parse_error_is_one_line() {
    let tmp = tempfile::tempdir().unwrap();
    std::fs::write(
        tmp.path().join("bad.toml"),
        "[scenario]\npath = \"s1\"\n[plant]\nfrictoin = true\n",
    )
    .unwrap();
    let out = deltaloop_in(tmp.path(), &["run", "bad.toml", "--mode", "inproc"]);
    let err = one_line_error(&out);
    assert!(
        err.starts_with("deltaloop: error: invalid config bad.toml: unknown field `frictoin`")
            && err.ends_with(" at line 4, column 1"),
        "{err}"
    );
    // A 200 KB value is not echoed whole.
    let long = "x".repeat(200_000);
    std::fs::write(
        tmp.path().join("bad.toml"),
        format!("[scenario]\npath = \"{long}\"\n"),
    )
    .unwrap();
    let out = deltaloop_in(tmp.path(), &["run", "bad.toml", "--mode", "inproc"]);
    let err = one_line_error(&out);
    assert!(err.len() < 500 && err.contains('…'), "{} bytes", err.len());
}

#[test]
fn regression_sweep_base_file_content_is_not_echoed() {
    let tmp = tempfile::tempdir().unwrap();
    let sweep = tmp.path().join("sw.toml");
    std::fs::write(
        &sweep,
        format!("name = \"p\"\nbase = \"/etc/passwd\"\n{AXES}"),
    )
    .unwrap();
    let out = deltaloop_in(tmp.path(), &["sweep", "sw.toml"]);
    let err = one_line_error(&out);
    assert!(!err.contains("root:"), "{err}");
    assert!(
        err.contains("/etc/passwd is not a valid scenario config (parse error at line 1, column"),
        "{err}"
    );
    // Duplicate laws are refused as `run` refuses them, naming the key and the value.
    std::fs::write(tmp.path().join("base.toml"), BASE).unwrap();
    std::fs::write(
        &sweep,
        format!(
            "name = \"d\"\nbase = \"base.toml\"\n{}",
            AXES.replace("[\"tdc\"]", "[\"tdc\", \"tdc\"]")
        ),
    )
    .unwrap();
    let out = deltaloop_in(tmp.path(), &["sweep", "sw.toml"]);
    assert_eq!(
        one_line_error(&out),
        "deltaloop: error: sweep key `laws` lists tdc twice: each value at most once"
    );
    assert_eq!(tree(tmp.path()).len(), 2, "no sweep folder");
}

#[test]
fn regression_interrupted_sweep_point_is_not_a_result() {
    let tmp = tempfile::tempdir().unwrap();
    // Long points (60 s held at RK4 h = 1 µs): both workers are mid-run at the interrupt.
    std::fs::write(
        tmp.path().join("base.toml"),
        "[scenario]\npath = \"s1\"\nhold_s = 60.0\n[plant]\nsubsteps = 300\n",
    )
    .unwrap();
    let sweep = tmp.path().join("sw.toml");
    std::fs::write(
        &sweep,
        format!(
            "name = \"int\"\nbase = \"base.toml\"\n{}",
            AXES.replace("[\"tdc\"]", "[\"tdc\", \"pid\"]")
        ),
    )
    .unwrap();
    let out_dir = tmp.path().join("out");
    let child = spawn(&[
        "sweep",
        sweep.to_str().unwrap(),
        "--out",
        out_dir.to_str().unwrap(),
    ]);
    let csv_path = out_dir.join("sweep.csv");
    let t0 = Instant::now();
    while !csv_path.exists() {
        assert!(
            t0.elapsed() < Duration::from_secs(10),
            "sweep.csv never appeared"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
    std::thread::sleep(Duration::from_millis(500));
    // SAFETY: signalling our own child.
    assert_eq!(unsafe { libc::kill(child.id() as i32, libc::SIGINT) }, 0);
    let out = finish_within(child, Duration::from_secs(10), "interrupted sweep");
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(130), "{err}");
    let mut rdr = csv::Reader::from_path(&csv_path).unwrap();
    let h = rdr.headers().unwrap().clone();
    let col = |n: &str| h.iter().position(|x| x == n).unwrap();
    let rows: Vec<csv::StringRecord> = rdr.records().map(Result::unwrap).collect();
    assert_eq!(rows.len(), 2, "both points were running");
    for r in &rows {
        assert_eq!(&r[col("status")], "interrupted", "{r:?}");
        assert!(
            r[col("reason")].starts_with("interrupted at tick "),
            "{r:?}"
        );
        assert_eq!(&r[col("diverged_at_tick")], "", "{r:?}");
        assert_eq!(&r[col("rms_rad")], "", "no result: {r:?}");
    }
    let report = std::fs::read_to_string(out_dir.join("report.md")).unwrap();
    assert!(
        report.contains("after 0 of 2 runs") && report.contains(" 0 points;"),
        "{report}"
    );
}

/// Regression: `export` read `summary.json` (and the trace and timing files) without the rule
/// every other input keeps: a FIFO hung it, a link to `/dev/zero` exhausted memory, a 100 MB file
/// was attached whole. Each of the run's files export reads is opened as a regular file only,
/// size-capped, and a bad one is refused at once in one line naming it, with no output left.
#[test]
fn regression_export_reads_only_regular_capped_files() {
    let tmp = tempfile::tempdir().unwrap();
    let run = tmp.path().join("run");
    let o = common::run_output("configs/s1-nominal.toml", "inproc", &run, &["--law", "tdc"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let r = run.to_str().unwrap();
    let keep = tmp.path().join("keep");
    std::fs::create_dir(&keep).unwrap();
    for name in ["summary.json", "trace.csv"] {
        std::fs::rename(run.join(name), keep.join(name)).unwrap();
    }
    let put_back = |name: &str| {
        let _ = std::fs::remove_file(run.join(name));
        std::fs::copy(keep.join(name), run.join(name)).unwrap();
    };
    let export = |case: &str| {
        let out = finish_within(
            spawn(&["export", r, "--mcap"]),
            Duration::from_secs(20),
            case,
        );
        assert!(!run.join("run.mcap").exists(), "{case}: an output was left");
        one_line_error(&out)
    };
    put_back("trace.csv");
    let summary = run.join("summary.json");
    mkfifo(&summary);
    let err = export("summary.json a FIFO");
    assert!(
        err.contains(&summary.display().to_string()) && err.contains("it is a FIFO"),
        "{err}"
    );
    std::fs::remove_file(&summary).unwrap();
    std::os::unix::fs::symlink("/dev/zero", &summary).unwrap();
    let err = export("summary.json a link to /dev/zero");
    assert!(
        err.contains("summary.json: it is a character device"),
        "{err}"
    );
    std::fs::remove_file(&summary).unwrap();
    let mut big = std::fs::read(keep.join("summary.json")).unwrap();
    big.resize(5 << 20, b' ');
    std::fs::write(&summary, big).unwrap();
    let err = export("summary.json of 5 MiB");
    assert!(
        err.contains("summary.json: it is 5242880 bytes, larger than 4 MiB"),
        "{err}"
    );
    put_back("summary.json");
    let trace = run.join("trace.csv");
    std::fs::remove_file(&trace).unwrap();
    mkfifo(&trace);
    let err = export("trace.csv a FIFO");
    assert!(err.contains("trace.csv: it is a FIFO"), "{err}");
    put_back("trace.csv");
    let timing = run.join("tdc.timing.csv");
    mkfifo(&timing);
    let err = export("tdc.timing.csv a FIFO");
    assert!(err.contains("tdc.timing.csv: it is a FIFO"), "{err}");
    std::fs::remove_file(&timing).unwrap();
    let out = deltaloop_in(
        Path::new(env!("CARGO_MANIFEST_DIR")),
        &["export", r, "--mcap"],
    );
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}
