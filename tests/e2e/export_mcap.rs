//! `deltaloop export RUN_DIR --mcap` read back by the MCAP readers of PyPI (the test venv's
//! `mcap` and `mcap-ros2-support`): every channel against trace.csv, row for row, bit for bit.

use crate::common;

use common::deltaloop;
use common::python::{python, root, run_cmd, text};
use std::process::Command;

/// The check script's line for `law`, after the export of a run of `config` in `mode`.
fn exported(mode: &str, extra: &[&str]) -> (String, std::path::PathBuf, tempfile::TempDir) {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("run");
    let mut args = vec![
        "run",
        "configs/s1-payload.toml",
        "--mode",
        mode,
        "--out",
        out.to_str().unwrap(),
    ];
    args.extend_from_slice(extra);
    let o = deltaloop(&args);
    assert!(o.status.success(), "run: {}", text(&o.stderr));
    let o = deltaloop(&["export", out.to_str().unwrap(), "--mcap"]);
    assert!(o.status.success(), "export: {}", text(&o.stderr));
    assert!(
        text(&o.stdout).contains("run.mcap: "),
        "{}",
        text(&o.stdout)
    );
    let check = run_cmd(
        Command::new(python())
            .arg(root().join("examples/foxglove/read_mcap.py"))
            .arg(&out),
        "read_mcap.py",
    );
    assert!(
        check.status.success(),
        "read_mcap.py: {}{}",
        text(&check.stdout),
        text(&check.stderr)
    );
    let said = text(&check.stdout);
    assert!(
        !said.contains("truncated"),
        "a finished export reads whole: {said}"
    );
    (said, out, tmp)
}

/// An in-process run (two laws, the payload step): every message the readers decode equals the
/// trace; one joint state, one control message and one scene per row; the events end with how
/// the run ended; the reference path is there once.
#[test]
fn an_exported_run_reads_back_bit_for_bit_with_the_pypi_readers() {
    let (said, _, _tmp) = exported("inproc", &["--law", "tdc", "--law", "tdc-is-sta"]);
    for law in ["tdc", "tdc-is-sta"] {
        let line = said
            .lines()
            .find(|l| l.starts_with(&format!("{law} ")))
            .unwrap_or_else(|| panic!("no line for {law}: {said}"));
        let n = |key: &str| -> u64 {
            line.split_whitespace()
                .find_map(|w| w.strip_prefix(&format!("{key}=")))
                .and_then(|v| v.parse().ok())
                .unwrap_or_else(|| panic!("no {key} in {line}"))
        };
        assert_eq!(n("rows"), 2668, "{line}");
        assert_eq!(n("joint_states"), n("rows"), "{line}");
        assert_eq!(n("scene"), n("rows"), "{line}");
        assert_eq!(n("timing"), 0, "inproc has no timing file: {line}");
        assert!(line.contains("last_event='run ok'"), "{line}");
    }
    assert!(said.contains("reference_path=1"), "{said}");
}

/// A lockstep run carries its timing rows too, one per tick; the `<law>.mcap` that `--mcap`
/// wrote while it recorded reads back whole and equal to the trace and the timing file; and a run folder that is not
/// one is refused in one line.
#[test]
fn a_process_run_exports_its_timing_and_a_non_run_is_refused() {
    let (said, out, _tmp) = exported("lockstep", &["--law", "tdc", "--mcap"]);
    let timing: u64 = said
        .split_whitespace()
        .find_map(|w| w.strip_prefix("timing="))
        .and_then(|v| v.parse().ok())
        .unwrap_or(0);
    assert!(timing >= 2668, "{said}");
    let live = run_cmd(
        Command::new(python())
            .arg(root().join("examples/foxglove/read_mcap.py"))
            .arg(&out)
            .arg(out.join("tdc.mcap")),
        "read_mcap.py",
    );
    let live_said = text(&live.stdout);
    assert!(live.status.success(), "{live_said}{}", text(&live.stderr));
    assert!(!live_said.contains("truncated"), "{live_said}");
    assert!(
        live_said.contains("tdc rows=2668 joint_states=2668"),
        "{live_said}"
    );
    assert!(live_said.contains("last_event='run ok'"), "{live_said}");
    // The live file's timing channel is the timing file's rows, as the export's is.
    assert!(
        live_said.contains(&format!(" timing={timing} ")),
        "{live_said}"
    );
    let o = deltaloop(&["export", out.join("nothing").to_str().unwrap(), "--mcap"]);
    assert!(!o.status.success());
    let err = text(&o.stderr);
    assert!(
        err.contains("is not a run folder") && err.lines().count() == 1,
        "{err}"
    );
}

/// `run --mcap` writes `<law>.mcap` while the law records, in lockstep and in realtime: killed
/// with -9 mid-run, the file reads back up to its last whole record, what it holds equals the
/// rows the trace part kept, and its timing channel equals the rows of `tdc.timing.csv`.
#[test]
fn a_live_mcap_reads_back_also_after_kill_9() {
    for mode in ["lockstep", "realtime"] {
        killed_mid_run(mode);
    }
}

fn killed_mid_run(mode: &str) {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("run");
    let cfg = tmp.path().join("long.toml");
    std::fs::write(
        &cfg,
        "name = \"long\"\n[scenario]\npath = \"s1\"\nhold_s = 60.0\n[controller]\nlaws = [\"tdc\"]\n",
    )
    .unwrap();
    let mut child = common::spawn_group(&[
        "run",
        cfg.to_str().unwrap(),
        "--mode",
        mode,
        "--mcap",
        "--out",
        out.to_str().unwrap(),
    ]);
    let live = out.join("tdc.mcap");
    let t0 = std::time::Instant::now();
    while std::fs::metadata(&live).map_or(0, |m| m.len()) < 4_000_000 {
        assert!(
            t0.elapsed() < std::time::Duration::from_secs(120),
            "{mode}: tdc.mcap did not grow"
        );
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    // SAFETY: killing the process group this test started.
    unsafe { libc::kill(-(child.id() as i32), libc::SIGKILL) };
    let _ = child.wait();
    let check = run_cmd(
        Command::new(python())
            .arg(root().join("examples/foxglove/read_mcap.py"))
            .arg(&out)
            .arg(&live)
            .arg(out.join("trace.tdc.part")),
        "read_mcap.py",
    );
    let said = text(&check.stdout);
    assert!(
        check.status.success(),
        "{mode}: {said}{}",
        text(&check.stderr)
    );
    assert!(said.starts_with("truncated"), "{mode}: {said}");
    let count = |what: &str| -> u64 {
        said.split_whitespace()
            .find_map(|w| w.strip_prefix(what))
            .and_then(|v| v.parse().ok())
            .unwrap_or(0)
    };
    assert!(count("joint_states=") > 1000, "{mode}: {said}");
    assert!(
        count("timing=") > 1000,
        "{mode}: the timing channel: {said}"
    );
}

/// An in-process run of one law in `tmp/run`, for the export's own rules.
fn short_run(tmp: &std::path::Path) -> std::path::PathBuf {
    let out = tmp.join("run");
    let o = deltaloop(&[
        "run",
        "configs/s1-nominal.toml",
        "--mode",
        "inproc",
        "--law",
        "tdc",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "run: {}", text(&o.stderr));
    out
}

/// `deltaloop export <run> --mcap --out <out> <extra…>`.
fn export_to(run: &std::path::Path, out: &std::path::Path, extra: &[&str]) -> std::process::Output {
    let mut args = vec![
        "export",
        run.to_str().unwrap(),
        "--mcap",
        "--out",
        out.to_str().unwrap(),
    ];
    args.extend_from_slice(extra);
    deltaloop(&args)
}

/// Every file of the run folder, by name, with its bytes.
fn files_of(dir: &std::path::Path) -> std::collections::BTreeMap<String, Vec<u8>> {
    std::fs::read_dir(dir)
        .unwrap()
        .flatten()
        .filter(|e| e.file_type().unwrap().is_file())
        .map(|e| {
            let name = e.file_name().to_string_lossy().into_owned();
            (name, std::fs::read(e.path()).unwrap())
        })
        .collect()
}

/// The first bytes of every MCAP file.
const MCAP_MAGIC: &[u8] = b"\x89MCAP0\r\n";

/// Regression: `export --out RUN/trace.csv` replaced the trace with MCAP bytes, `--out
/// RUN/config.toml` made the config an MCAP that embedded itself, a link was written through and
/// any existing file replaced. An output that is one of the run's files (by name, through `..`,
/// a symbolic link or a hard link) is refused, `--force` or not; a link is never written
/// through; an existing file is replaced only with `--force`; each refusal is one line naming
/// the path, and leaves every file as it was.
#[test]
fn regression_export_refuses_out_that_is_a_run_input() {
    let tmp = tempfile::tempdir().unwrap();
    let run = short_run(tmp.path());
    let before = files_of(&run);
    let refused = |out: &std::path::Path, extra: &[&str], says: &str| {
        let o = export_to(&run, out, extra);
        let err = common::one_line_error(&o);
        assert!(
            err.contains(&out.display().to_string()) && err.contains(says),
            "{out:?} {extra:?}: {err}"
        );
        assert_eq!(files_of(&run), before, "{out:?} {extra:?} changed the run");
    };
    let dotdot = run.join("..").join("run").join("summary.json");
    let hard = tmp.path().join("hard.csv");
    std::fs::hard_link(run.join("trace.csv"), &hard).unwrap();
    let soft = tmp.path().join("soft.mcap");
    std::os::unix::fs::symlink(run.join("config.toml"), &soft).unwrap();
    for force in [&[][..], &["--force"][..]] {
        refused(&run.join("trace.csv"), force, "is the run's trace.csv");
        refused(&run.join("config.toml"), force, "is the run's config.toml");
        refused(&dotdot, force, "is the run's summary.json");
        refused(&hard, force, "is a hard link to the run's trace.csv");
        refused(&soft, force, "is the run's config.toml");
    }
    // A link elsewhere is not written through, even with --force.
    let victim = tmp.path().join("victim.txt");
    std::fs::write(&victim, "keep me").unwrap();
    let link = tmp.path().join("link.mcap");
    std::os::unix::fs::symlink(&victim, &link).unwrap();
    for force in [&[][..], &["--force"][..]] {
        refused(&link, force, "is a symbolic link");
    }
    assert_eq!(std::fs::read_to_string(&victim).unwrap(), "keep me");
    // An existing file: refused without --force, replaced with it.
    let old = tmp.path().join("old.mcap");
    std::fs::write(&old, "an older file").unwrap();
    refused(&old, &[], "--force");
    assert_eq!(std::fs::read_to_string(&old).unwrap(), "an older file");
    let o = export_to(&run, &old, &["--force"]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    assert!(std::fs::read(&old).unwrap().starts_with(MCAP_MAGIC));
    // The default output is no exception: a second export needs --force.
    let o = deltaloop(&["export", run.to_str().unwrap(), "--mcap"]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    let o = deltaloop(&["export", run.to_str().unwrap(), "--mcap"]);
    let err = common::one_line_error(&o);
    assert!(
        err.contains("run.mcap exists (an earlier export)")
            && err.contains("--force")
            && !err.contains("--out /"),
        "the user gave no --out: {err}"
    );
    let o = deltaloop(&["export", run.to_str().unwrap(), "--mcap", "--force"]);
    assert!(o.status.success(), "{}", text(&o.stderr));
}

/// Regression: an export that failed half-way left a partial MCAP that readers opened without
/// complaint, in place of the previous good one (`--force` too). The file is written under a
/// temporary name and renamed only once whole: a failure exits 1, leaves the previous file byte
/// for byte, and no temporary file.
#[test]
fn regression_failed_export_keeps_the_previous_file() {
    let tmp = tempfile::tempdir().unwrap();
    let run = short_run(tmp.path());
    let o = deltaloop(&["export", run.to_str().unwrap(), "--mcap"]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    let good = std::fs::read(run.join("run.mcap")).unwrap();
    // A bad cell far down the trace: the export fails after writing most of the rows.
    let trace = std::fs::read_to_string(run.join("trace.csv")).unwrap();
    let mut lines: Vec<&str> = trace.lines().collect();
    let bad = lines[2500].replacen("tdc,2499,", "tdc,not-a-tick,", 1);
    lines[2500] = &bad;
    std::fs::write(run.join("trace.csv"), lines.join("\n") + "\n").unwrap();
    for out in [run.join("run.mcap"), tmp.path().join("new.mcap")] {
        let o = export_to(&run, &out, &["--force"]);
        let err = common::one_line_error(&o);
        assert!(err.contains("trace.csv line 2501"), "{err}");
        let dir = out.parent().unwrap();
        let names: Vec<String> = std::fs::read_dir(dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        assert!(!names.iter().any(|n| n.ends_with(".tmp")), "{names:?}");
    }
    assert!(
        std::fs::read(run.join("run.mcap")).unwrap() == good,
        "the previous run.mcap was replaced"
    );
    assert!(!tmp.path().join("new.mcap").exists());
}

/// The same on a real full disk (a 4 MiB tmpfs in a private mount namespace, most of it taken):
/// the export exits 1 naming its output, the previous file stays, and no temporary file is left.
/// Needs root (CI runs as root).
#[test]
fn regression_failed_export_keeps_the_previous_file_on_a_full_disk() {
    // SAFETY: geteuid has no preconditions.
    if unsafe { libc::geteuid() } != 0 {
        eprintln!(
            "SKIPPED regression_failed_export_keeps_the_previous_file_on_a_full_disk: needs root to mount a small tmpfs in a private mount namespace"
        );
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let src = short_run(tmp.path());
    let (disk, keep) = (tmp.path().join("disk"), tmp.path().join("keep"));
    std::fs::create_dir(&disk).unwrap();
    std::fs::create_dir(&keep).unwrap();
    // The namespace goes with the shell: what the export left is listed before it ends.
    let script = r#"
mount -t tmpfs -o size=4m tmpfs "$DISK" || exit 90
mkdir "$DISK/run"
cp "$SRC/config.toml" "$SRC/summary.json" "$SRC/trace.csv" "$DISK/run/"
printf 'the previous export' > "$DISK/run/run.mcap"
dd if=/dev/zero of="$DISK/fill" bs=4k count=400 2>/dev/null
"$BIN" export "$DISK/run" --mcap --force 2>"$KEEP/stderr"
echo $? > "$KEEP/rc"
ls -A "$DISK/run" > "$KEEP/names"
cp "$DISK/run/run.mcap" "$KEEP/run.mcap"
"#;
    let o = Command::new("unshare")
        .args(["--mount", "--propagation", "private", "sh", "-c", script])
        .env("DISK", &disk)
        .env("KEEP", &keep)
        .env("SRC", &src)
        .env("BIN", env!("CARGO_BIN_EXE_deltaloop"))
        .output()
        .expect("unshare runs");
    assert!(
        o.status.success(),
        "cannot mount a tmpfs in a private mount namespace (unshare --mount, as root): {}",
        text(&o.stderr)
    );
    let read = |name: &str| std::fs::read_to_string(keep.join(name)).unwrap();
    let err = read("stderr");
    assert_eq!(read("rc").trim(), "1", "{err}");
    assert_eq!(err.trim().lines().count(), 1, "{err}");
    let out = disk.join("run").join("run.mcap");
    assert!(
        err.contains(&format!("cannot write {}", out.display()))
            && err.contains("No space left on device"),
        "{err}"
    );
    assert_eq!(read("run.mcap"), "the previous export");
    assert_eq!(
        read("names").split_whitespace().collect::<Vec<_>>(),
        ["config.toml", "run.mcap", "summary.json", "trace.csv"]
    );
}
