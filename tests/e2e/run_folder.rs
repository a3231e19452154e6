//! The run folder belongs to one run: a non-empty `--out` is refused unless `--force` (which
//! only ever empties a deltaloop folder), and two runs never share a folder.

use crate::common;

use common::deltaloop;
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

fn run(cfg: &str, mode: &str, out: &Path, extra: &[&str]) -> (Option<i32>, String) {
    let mut args = vec![
        "run",
        cfg,
        "--mode",
        mode,
        "--law",
        "tdc",
        "--out",
        out.to_str().unwrap(),
    ];
    args.extend_from_slice(extra);
    let o = deltaloop(&args);
    (
        o.status.code(),
        String::from_utf8_lossy(&o.stderr).into_owned(),
    )
}

/// Starts `deltaloop <args>` in the background and waits until its run folder `out` holds the
/// resolved config (the run has claimed the folder and is under way).
fn start(args: &[&str], out: &Path) -> std::process::Child {
    let child = Command::new(env!("CARGO_BIN_EXE_deltaloop"))
        .args(args)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let t0 = Instant::now();
    while !out.join("config.toml").exists() {
        assert!(
            t0.elapsed() < Duration::from_secs(20),
            "the run never started"
        );
        std::thread::sleep(Duration::from_millis(2));
    }
    child
}

/// Regression: two runs with the same --out both exited 0 and mixed their files.
#[test]
fn regression_reused_out_is_refused_unless_forced() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("run");
    let cfg = "configs/s1-nominal.toml";
    assert_eq!(run(cfg, "inproc", &out, &[]).0, Some(0));
    std::fs::write(out.join("stale.txt"), "from an old run").unwrap();

    let (code, err) = run(cfg, "inproc", &out, &[]);
    assert_eq!(code, Some(1), "{err}");
    assert_eq!(err.trim().lines().count(), 1, "{err}");
    assert!(
        err.contains("is not empty") && err.contains("--force"),
        "{err}"
    );
    assert!(
        out.join("stale.txt").exists(),
        "a refused run touches nothing"
    );

    let (code, err) = run(cfg, "inproc", &out, &["--force"]);
    assert_eq!(code, Some(0), "{err}");
    assert!(
        !out.join("stale.txt").exists(),
        "--force empties the old run first"
    );
    assert!(out.join("trace.csv").exists() && out.join("summary.json").exists());
}

#[test]
fn force_never_empties_a_folder_that_is_not_a_run() {
    let tmp = tempfile::tempdir().unwrap();
    let keep = tmp.path().join("notes.txt");
    std::fs::write(&keep, "precious").unwrap();
    let (code, err) = run(
        "configs/s1-nominal.toml",
        "inproc",
        tmp.path(),
        &["--force"],
    );
    assert_eq!(code, Some(1), "{err}");
    assert!(
        err.contains("does not look like a deltaloop run folder"),
        "{err}"
    );
    assert_eq!(std::fs::read_to_string(&keep).unwrap(), "precious");
}

/// Two runs at once into one folder: the second is refused while the first holds it, even with
/// --force, and the first, realtime, is untouched: it ends with its own status and every tick of
/// it on disk. That it completed depends on timing: judged on a run the machine left alone.
#[test]
fn regression_concurrent_runs_never_share_a_folder() {
    let test = "regression_concurrent_runs_never_share_a_folder";
    let tmp = tempfile::tempdir().unwrap();
    let cfg = tmp.path().join("cfg.toml");
    std::fs::write(
        &cfg,
        "name = \"held\"\n[scenario]\npath = \"s1\"\nhold_s = 1.0\n[controller]\nlaws = [\"tdc\"]\n",
    )
    .unwrap();
    common::on_a_noisy_host(test, |n| {
        let out = tmp.path().join(format!("run-{n}"));
        let first = start(
            &[
                "run",
                cfg.to_str().unwrap(),
                "--mode",
                "realtime",
                "--out",
                out.to_str().unwrap(),
            ],
            &out,
        );
        let (code, err) = run(cfg.to_str().unwrap(), "inproc", &out, &["--force"]);
        assert_eq!(code, Some(1), "{err}");
        assert!(err.contains("in use by another deltaloop run"), "{err}");
        let o = first.wait_with_output().unwrap();
        let s = common::summary(&out);
        assert_eq!(s["mode"], "realtime");
        let status = common::assert_every_tick_on_disk(&s, &out, "tdc");
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.success(), status == common::RunStatus::Ok, "{err}");
        common::judge(
            common::disturbance(&s, "tdc"),
            (status == common::RunStatus::Ok)
                .then_some(())
                .ok_or_else(|| format!("{status:?}: {err}")),
        )
    });
}

/// Regression: on a full disk the error ("No space left on device") named no file, and laws that
/// had finished lost their trace and summary. Simulated by a write that fails for the second law
/// (its timing.csv path is taken by a folder): the error names the file, and the first law's
/// trace, summary and report are written.
#[test]
fn regression_a_failed_write_names_its_file_and_keeps_finished_laws() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("run");
    let child = start(
        &[
            "run",
            "configs/s1-nominal.toml",
            "--mode",
            "lockstep",
            "--law",
            "tdc",
            "--law",
            "tde-is",
            "--out",
            out.to_str().unwrap(),
        ],
        &out,
    );
    let blocker = out.join("tde-is.timing.csv");
    std::fs::create_dir(&blocker).unwrap();
    let o = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert_eq!(err.trim().lines().count(), 1, "{err}");
    assert!(
        err.contains(&blocker.display().to_string()),
        "names the file: {err}"
    );
    let s = common::summary(&out);
    assert_eq!(
        common::outcome(&s, "tdc"),
        (common::RunStatus::Ok, None),
        "{s}"
    );
    let trace = std::fs::read_to_string(out.join("trace.csv")).unwrap();
    assert!(trace.lines().filter(|l| l.starts_with("tdc,")).count() > 2000);
    assert!(out.join("report.md").exists() && out.join("tdc.timing.csv").is_file());
}

/// `[record]` turns the per-tick files off one by one; the rest of the run folder (summary,
/// report, histograms, interval logs, figures) and every metric stay the same, and replay of a
/// run with no trace says why it cannot.
#[test]
fn record_section_turns_off_the_per_tick_files_and_nothing_else() {
    let tmp = tempfile::tempdir().unwrap();
    let mut rms = Vec::new();
    for (trace, timing) in [(false, true), (true, false)] {
        let out = tmp.path().join(format!("run-{trace}-{timing}"));
        let cfg = tmp.path().join(format!("cfg-{trace}-{timing}.toml"));
        std::fs::write(
            &cfg,
            format!("name = \"rec\"\n[scenario]\npath = \"s1\"\nhold_s = 0.2\n[controller]\nlaws = [\"tdc\", \"tde-is\"]\n[record]\ntrace = {trace}\ntiming_csv = {timing}\n"),
        )
        .unwrap();
        let s = common::run(cfg.to_str().unwrap(), "lockstep", &out, &[]);
        for law in ["tdc", "tde-is"] {
            common::assert_complete(&s, &out, law);
            assert_eq!(
                out.join(format!("{law}.timing.csv")).exists(),
                timing,
                "{law}"
            );
            for f in [
                "round_trip.hgrm",
                "round_trip.hlog",
                "latency.png",
                "timeline.svg",
            ] {
                assert!(out.join(format!("{law}.{f}")).is_file(), "{law}.{f}");
            }
        }
        assert_eq!(out.join("trace.csv").exists(), trace);
        let names: Vec<String> = std::fs::read_dir(&out)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        assert!(!names.iter().any(|n| n.ends_with(".part")), "{names:?}");
        assert!(out.join("report.md").is_file());
        rms.push(s["laws"]["tde-is"]["rms_rad"].clone());
        let o = deltaloop(&["replay", out.to_str().unwrap()]);
        let err = String::from_utf8_lossy(&o.stderr);
        if trace {
            assert!(o.status.success(), "{err}");
        } else {
            assert_eq!(o.status.code(), Some(1), "{err}");
            assert!(
                err.contains(
                    "has no trace.csv to replay: the run was recorded with record.trace = false"
                ),
                "{err}"
            );
        }
    }
    assert_eq!(
        rms[0], rms[1],
        "lockstep metrics do not depend on what is written"
    );
}

/// Regression: on a full disk the finished law's complete trace stayed `trace.tdc.part`,
/// `summary.json` was left at 0 bytes, and the error named `summary.json` rather than the file
/// the law could not write. A real full disk: a 32 MiB tmpfs in a private mount namespace, filled
/// while the second law records. The error names the second law's file; the first law's trace is
/// `trace.csv`, whole; the second law's rows are in `trace.tde-is.csv`; `summary.json` and
/// `report.md` are whole or absent, and no temporary file is left. Needs root (CI runs as root).
#[test]
fn regression_a_full_disk_keeps_finished_laws_and_no_cut_files() {
    // SAFETY: geteuid has no preconditions.
    if unsafe { libc::geteuid() } != 0 {
        eprintln!(
            "SKIPPED regression_a_full_disk_keeps_finished_laws_and_no_cut_files: needs root to mount a small tmpfs in a private mount namespace"
        );
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let (disk, keep) = (tmp.path().join("disk"), tmp.path().join("keep"));
    std::fs::create_dir(&disk).unwrap();
    std::fs::create_dir(&keep).unwrap();
    let cfg = tmp.path().join("two.toml");
    std::fs::write(
        &cfg,
        "name = \"full\"\n[scenario]\npath = \"s1\"\nhold_s = 3.0\n[controller]\nlaws = [\"tdc\", \"tde-is\"]\n",
    )
    .unwrap();
    // The namespace goes with the shell: what the run left is copied out before it ends.
    let script = r#"
mount -t tmpfs -o size=32m tmpfs "$DISK" || exit 90
"$BIN" run "$CFG" --mode lockstep --out "$DISK/run" 2>"$KEEP/stderr" &
pid=$!
while [ ! -s "$DISK/run/trace.tde-is.part" ] && kill -0 $pid 2>/dev/null; do sleep 0.01; done
dd if=/dev/zero of="$DISK/fill" bs=4k 2>/dev/null
wait $pid
echo $? > "$KEEP/rc"
cp -a "$DISK/run" "$KEEP/run"
"#;
    let o = Command::new("unshare")
        .args(["--mount", "--propagation", "private", "sh", "-c", script])
        .env("DISK", &disk)
        .env("KEEP", &keep)
        .env("CFG", &cfg)
        .env("BIN", env!("CARGO_BIN_EXE_deltaloop"))
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .expect("unshare runs");
    assert!(
        o.status.success(),
        "cannot mount a tmpfs in a private mount namespace (unshare --mount, as root): {}",
        String::from_utf8_lossy(&o.stderr)
    );
    let err = std::fs::read_to_string(keep.join("stderr")).unwrap();
    let rc = std::fs::read_to_string(keep.join("rc")).unwrap();
    assert_eq!(rc.trim(), "1", "{err}");
    assert_eq!(err.trim().lines().count(), 1, "{err}");
    let run = disk.join("run").display().to_string();
    assert!(
        err.starts_with(&format!(
            "deltaloop: error: lockstep run of `tde-is`: cannot write {run}/"
        )) && err.contains("No space left on device"),
        "names the law's file first: {err}"
    );
    let kept = keep.join("run");
    let names: Vec<String> = std::fs::read_dir(&kept)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    assert!(
        !names
            .iter()
            .any(|n| n.ends_with(".tmp") || n == "trace.tdc.part"),
        "{names:?}"
    );
    let trace = std::fs::read_to_string(kept.join("trace.csv")).unwrap();
    let ticks: Vec<&str> = trace.lines().skip(1).collect();
    assert!(
        ticks.iter().all(|l| l.starts_with("tdc,")),
        "only tdc's rows"
    );
    assert_eq!(ticks.len(), 12668, "every tick of tdc, 0..=N");
    let theirs = std::fs::read_to_string(kept.join("trace.tde-is.csv")).unwrap();
    assert_eq!(
        trace.lines().next(),
        theirs.lines().next(),
        "the same header"
    );
    for (name, whole) in [("summary.json", "\"tdc\""), ("report.md", "tdc")] {
        match std::fs::read_to_string(kept.join(name)) {
            Ok(text) => assert!(text.contains(whole), "{name} is cut: {text:?}"),
            Err(e) => assert_eq!(e.kind(), std::io::ErrorKind::NotFound, "{name}"),
        }
        if !kept.join(name).exists() {
            assert!(err.contains(&format!("cannot write {run}/{name}")), "{err}");
        }
    }
    if let Ok(text) = std::fs::read_to_string(kept.join("summary.json")) {
        let s: serde_json::Value = serde_json::from_str(&text).expect("summary.json is whole");
        assert_eq!(s["laws"]["tdc"]["status"], "ok");
    }
}
