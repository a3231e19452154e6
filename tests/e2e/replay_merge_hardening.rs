//! End-to-end (issue 25, items 1–5 and 10): `deltaloop replay` and `deltaloop sweep plan | merge`
//! never destroy a folder they were not given to write, never block on or drown in a file that
//! is not a regular file, refuse a sweep too large to hold, never copy through a link, and
//! replay's "byte for byte" means every byte.

use crate::common;

use common::{deltaloop, finish_within, mkfifo, one_line_error, run, spawn};
use std::path::{Path, PathBuf};
use std::process::Output;
use std::time::Duration;

/// A short in-process run of one law into `dir`.
fn a_run(dir: &Path) {
    run("configs/s2-fast.toml", "inproc", dir, &["--law", "tdc"]);
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// Every file under `dir` with its bytes (not the lock files), sorted: to see that nothing was
/// touched.
fn snapshot(dir: &Path) -> Vec<(PathBuf, Vec<u8>)> {
    let mut v = Vec::new();
    for e in std::fs::read_dir(dir).unwrap().flatten() {
        let (p, t) = (e.path(), e.file_type().unwrap());
        if t.is_dir() {
            v.extend(snapshot(&p));
        } else if !p.ends_with(".deltaloop-lock") {
            let bytes = if t.is_file() {
                std::fs::read(&p).unwrap()
            } else {
                Vec::new()
            };
            v.push((p, bytes));
        }
    }
    v.sort();
    v
}

fn ok(o: &Output) -> String {
    let out = String::from_utf8_lossy(&o.stdout).into_owned();
    assert!(
        o.status.success(),
        "{out}{}",
        String::from_utf8_lossy(&o.stderr)
    );
    out
}

/// A one-point in-process sweep shard in `tmp/shard` (its sweep file `tmp/sw.toml`).
fn a_shard(tmp: &Path) -> PathBuf {
    std::fs::write(
        tmp.join("base.toml"),
        "[scenario]\npath = \"s1\"\n[controller]\nlaws = [\"tdc\"]\n",
    )
    .unwrap();
    std::fs::write(
        tmp.join("sw.toml"),
        "name = \"h\"\nbase = \"base.toml\"\nscenarios = [\"s1\"]\npresets = [\"matched\"]\nlaws = [\"tdc\"]\ntde_delay_samples = [1]\ntransport_delay_samples = [0]\n",
    )
    .unwrap();
    let shard = tmp.join("shard");
    ok(&deltaloop(&[
        "sweep",
        "run",
        s(&tmp.join("sw.toml")),
        "--out",
        s(&shard),
    ]));
    shard
}

/// Regression: `replay RUN --out OTHER` emptied OTHER without `--force` (19 of a finished run's
/// 20 files gone) and still said "reproduced byte for byte". `--out` now follows `run --out`'s
/// rules: a non-empty folder only with `--force`.
#[test]
fn regression_replay_out_other_run_is_refused_without_force() {
    let tmp = tempfile::tempdir().unwrap();
    let (r1, r2) = (tmp.path().join("r1"), tmp.path().join("r2"));
    a_run(&r1);
    a_run(&r2);
    let before = snapshot(&r2);
    let err = one_line_error(&deltaloop(&["replay", s(&r1), "--out", s(&r2)]));
    assert!(
        err.contains("is not empty") && err.contains("--force"),
        "{err}"
    );
    assert_eq!(snapshot(&r2), before, "the other run was touched");
    // Asked for with --force, it is emptied and reused, as `run --out r2 --force` would.
    let out = ok(&deltaloop(&["replay", s(&r1), "--out", s(&r2), "--force"]));
    assert!(out.contains("reproduced byte for byte"), "{out}");
    assert_eq!(
        std::fs::read(r2.join("trace.csv")).unwrap(),
        std::fs::read(r1.join("trace.csv")).unwrap()
    );
}

/// Regression: `replay RUN --out RUN` emptied the run it replayed. The run folder itself, a
/// folder holding it and one inside it are refused, `--force` or not, however spelled; the
/// default folder RUN/replay is still the replay's own, reused.
#[test]
fn regression_replay_out_source_or_around_it_is_refused_even_with_force() {
    let tmp = tempfile::tempdir().unwrap();
    let r1 = tmp.path().join("r1");
    a_run(&r1);
    let before = snapshot(tmp.path());
    let spelled = tmp.path().join("r1/../r1/.");
    for (out, how) in [
        (r1.clone(), "is the run folder being replayed"),
        (spelled, "is the run folder being replayed"),
        (
            tmp.path().to_path_buf(),
            "contains the run folder being replayed",
        ),
        (r1.join("sub"), "is inside the run folder being replayed"),
    ] {
        let err = one_line_error(&deltaloop(&["replay", s(&r1), "--out", s(&out), "--force"]));
        assert!(
            err.contains(how) && err.contains("--force does not change this"),
            "{}: {err}",
            out.display()
        );
        assert_eq!(snapshot(tmp.path()), before, "{}", out.display());
    }
    for _ in 0..2 {
        let out = ok(&deltaloop(&["replay", s(&r1)]));
        assert!(out.contains("reproduced byte for byte"), "{out}");
    }
    let out = ok(&deltaloop(&[
        "replay",
        s(&r1),
        "--out",
        s(&r1.join("replay")),
    ]));
    assert!(out.contains("reproduced byte for byte"), "{out}");
}

/// Regression: a run folder whose `replay` entry is a symbolic link made a plain `replay RUN`
/// empty the link's target. A link is never claimed: refused, the target untouched.
#[test]
fn regression_replay_folder_symlink_is_refused_and_its_target_kept() {
    let tmp = tempfile::tempdir().unwrap();
    let (r1, victim) = (tmp.path().join("r1"), tmp.path().join("victim"));
    a_run(&r1);
    std::fs::create_dir(&victim).unwrap();
    // It even looks like a deltaloop folder, which --force would empty.
    std::fs::write(victim.join("config.toml"), "precious").unwrap();
    std::fs::write(victim.join("notes.txt"), "precious too").unwrap();
    std::os::unix::fs::symlink(&victim, r1.join("replay")).unwrap();
    let before = snapshot(&victim);
    let err = one_line_error(&deltaloop(&["replay", s(&r1)]));
    assert!(
        err.contains("replay is a symbolic link") && err.contains("never writes through a link"),
        "{err}"
    );
    assert_eq!(snapshot(&victim), before);
    // An explicit --out that is a link, with --force: the same.
    let link = tmp.path().join("link");
    std::os::unix::fs::symlink(&victim, &link).unwrap();
    let err = one_line_error(&deltaloop(&[
        "replay",
        s(&r1),
        "--out",
        s(&link),
        "--force",
    ]));
    assert!(err.contains("is a symbolic link"), "{err}");
    assert_eq!(snapshot(&victim), before);
}

/// Regression: a FIFO where replay or merge reads a file blocked for ever (SIGINT and SIGTERM
/// did not end it), and a link to /dev/zero grew memory until the OOM killer. Both are refused
/// at once, naming the file; a hang fails the test instead of hanging it.
#[test]
fn regression_fifo_or_device_trace_or_shard_file_is_refused_not_read() {
    let tmp = tempfile::tempdir().unwrap();
    let run_dir = tmp.path().join("r");
    a_run(&run_dir);
    let trace = run_dir.join("trace.csv");
    let shard = a_shard(tmp.path());
    let limit = Duration::from_secs(20);
    let fifo = |p: &Path| {
        std::fs::remove_file(p).unwrap();
        mkfifo(p);
    };
    let zero = |p: &Path| {
        std::fs::remove_file(p).unwrap();
        std::os::unix::fs::symlink("/dev/zero", p).unwrap();
    };
    for (make, kind) in [
        (&fifo as &dyn Fn(&Path), "a FIFO (named pipe)"),
        (&zero, "a character device"),
    ] {
        make(&trace);
        let err = one_line_error(&finish_within(
            spawn(&["replay", s(&run_dir)]),
            limit,
            "replay of a FIFO or device trace",
        ));
        assert!(
            err.contains(&format!("trace.csv: it is {kind}, not a regular file")),
            "{err}"
        );
    }
    let out = tmp.path().join("merged");
    for (file, make) in [
        ("sweep.csv", &fifo as &dyn Fn(&Path)),
        ("sweep.csv", &zero),
        ("shard.json", &fifo),
    ] {
        let p = shard.join(file);
        let keep = std::fs::read(&p).ok();
        make(&p);
        let err = one_line_error(&finish_within(
            spawn(&["sweep", "merge", s(&shard), "--out", s(&out)]),
            limit,
            "merge of a FIFO or device",
        ));
        assert!(
            err.contains(file) && err.contains("not a regular file"),
            "{file}: {err}"
        );
        assert!(!out.exists(), "a refused merge wrote {}", out.display());
        std::fs::remove_file(&p).unwrap();
        std::fs::write(&p, keep.unwrap_or_default()).unwrap();
    }
    ok(&deltaloop(&["sweep", "merge", s(&shard), "--out", s(&out)]));
}

/// Regression: nothing bounded a sweep's size: a 98 KB sweep file of 10⁸ points aborted
/// `sweep plan` on allocation, and `sweep merge` of a shard carrying it aborted before checking
/// anything. The count is checked first, with the axes, their product and the cap named.
#[test]
fn regression_sweep_of_1e8_points_is_refused_before_anything_is_allocated() {
    let tmp = tempfile::tempdir().unwrap();
    let shard = a_shard(tmp.path());
    let axis = (0..10_000)
        .map(|i| i.to_string())
        .collect::<Vec<_>>()
        .join(",");
    let big = format!(
        "name = \"big\"\nbase = \"base.toml\"\nscenarios = [\"s1\"]\npresets = [\"matched\"]\nlaws = [\"tdc\"]\ntde_delay_samples = [{axis}]\ntransport_delay_samples = [{axis}]\n"
    );
    let path = tmp.path().join("big.toml");
    std::fs::write(&path, &big).unwrap();
    let limit = Duration::from_secs(20);
    let said = "the sweep has 100000000 points: scenarios 1 × presets 1 × laws 1 × (tde_delay_samples 10000 × transport_delay_samples 10000 + transport_delay_us 0 + compute_delay_us 0), more than the 100000 a sweep may have";
    for args in [vec!["sweep", "plan", s(&path)], vec!["sweep", s(&path)]] {
        let err = one_line_error(&finish_within(
            spawn(&args),
            limit,
            "a sweep of 10^8 points",
        ));
        assert!(err.contains(said), "{args:?}: {err}");
    }
    std::fs::write(shard.join("sweep.toml"), &big).unwrap();
    let err = one_line_error(&finish_within(
        spawn(&[
            "sweep",
            "merge",
            s(&shard),
            "--out",
            s(&tmp.path().join("m")),
        ]),
        limit,
        "a merge of a shard of 10^8 points",
    ));
    assert!(err.contains("shard") && err.contains(said), "{err}");
}

/// Regression: a shard whose `points` entry was a symbolic link made `sweep merge` copy the
/// link's target (any folder) into the output. A link anywhere in `points/` is refused with a
/// line naming it, before anything is written; real folders and files are copied.
#[test]
fn regression_merge_never_follows_a_points_symlink() {
    let tmp = tempfile::tempdir().unwrap();
    let shard = a_shard(tmp.path());
    let secret = tmp.path().join("secret");
    std::fs::create_dir(&secret).unwrap();
    std::fs::write(secret.join("key"), "not for the sweep").unwrap();
    let out = tmp.path().join("merged");
    let merge = || deltaloop(&["sweep", "merge", s(&shard), "--out", s(&out)]);
    let points = shard.join("points");
    std::os::unix::fs::symlink(&secret, &points).unwrap();
    let err = one_line_error(&merge());
    assert!(
        err.contains(&format!("{} is a symbolic link", points.display()))
            && err.contains("never follows a link"),
        "{err}"
    );
    assert!(!out.exists(), "a refused merge wrote {}", out.display());
    // A link deeper in.
    std::fs::remove_file(&points).unwrap();
    std::fs::create_dir_all(points.join("run")).unwrap();
    let inner = points.join("run/trace.csv");
    std::os::unix::fs::symlink(secret.join("key"), &inner).unwrap();
    let err = one_line_error(&merge());
    assert!(
        err.contains(&format!("{} is a symbolic link", inner.display())),
        "{err}"
    );
    assert!(!out.exists());
    // Real files are copied.
    std::fs::remove_file(&inner).unwrap();
    std::fs::write(&inner, "law,k\n").unwrap();
    ok(&merge());
    assert_eq!(
        std::fs::read(out.join("points/run/trace.csv")).unwrap(),
        b"law,k\n"
    );
}

/// Regression: replay's "byte for byte" skipped the header and the line ends, a header alone
/// was "reproduced (0 rows)", and an arrival of u64::MAX was taken (it wrapped around inside
/// the drives). Every byte is compared now, with the first difference named; an empty trace
/// and an arrival no tick allows are refused, naming the line, column and value.
#[test]
fn regression_replay_compares_every_byte_and_refuses_empty_or_absurd_traces() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("r");
    a_run(&dir);
    let trace = dir.join("trace.csv");
    let good = std::fs::read_to_string(&trace).unwrap();
    let lines: Vec<&str> = good.lines().collect();
    let mut absurd: Vec<String> = lines.iter().map(|l| l.to_string()).collect();
    let mut row: Vec<&str> = lines[5].split(',').collect();
    assert_eq!(row[row.len() - 3], "applied", "{}", lines[5]);
    let max = u64::MAX.to_string();
    *row.last_mut().unwrap() = &max;
    absurd[5] = row.join(",");
    let cases = [
        (
            good.replace('\n', "\r\n"),
            "differs first at line 1 (the header), column line end: recorded \"\\r\\n\", replayed \"\\n\"",
        ),
        (
            good.replacen(",t_s,", ",time,", 1),
            "differs first at line 1 (the header), column time: recorded \"time\", replayed \"t_s\"",
        ),
        (
            good.trim_end().to_string(),
            &*format!(
                "differs first at line {} (tick {}), column line end: recorded none (the file ends), replayed \"\\n\"",
                lines.len(),
                lines.len() - 2
            ),
        ),
        (
            format!("{}\n", lines[0]),
            "trace.csv has no ticks (a header and no rows): there is nothing to replay",
        ),
        (
            absurd.join("\n") + "\n",
            "trace.csv line 6 (tick 4): column arrival_ns = 18446744073709551615 is out of range: an applied reply arrives 0..=",
        ),
    ];
    for (text, needle) in cases {
        std::fs::write(&trace, text).unwrap();
        let err = one_line_error(&deltaloop(&["replay", s(&dir)]));
        assert!(err.contains(needle), "{needle}\n{err}");
        // A trace refused before anything ran leaves no empty replay folder behind.
        if needle.contains("nothing to replay") {
            assert!(
                !dir.join("replay").exists(),
                "{needle}: replay/ left behind"
            );
        }
    }
    std::fs::write(&trace, &good).unwrap();
    let out = ok(&deltaloop(&["replay", s(&dir)]));
    assert!(
        out.contains(&format!(
            "reproduced byte for byte ({} rows)",
            lines.len() - 1
        )),
        "{out}"
    );
}
