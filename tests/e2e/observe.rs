//! The supervisor's recording as the loop runs: what a killed run leaves on disk, and what a
//! full disk does to it.

use crate::common::{children_mentioning, spawn_group};
use std::path::Path;
use std::time::{Duration, Instant};

/// A fault-test layout (unpinned, SCHED_OTHER: tests run in parallel), `hold_s` of hold after
/// S1's motion, and `extra` TOML.
fn config(dir: &Path, hold_s: f64, extra: &str) -> String {
    let p = dir.join("cfg.toml");
    let layout = "[loop.realtime]\nplant_cpu = -1\ncontroller_cpu = -1\nsupervisor_cpu = -1\nplant_priority = 0\ncontroller_priority = 0\nwake_early_us = 0\nlock_memory = false\n";
    std::fs::write(
        &p,
        format!(
            "name = \"observe\"\n[scenario]\npath = \"s1\"\nhold_s = {hold_s}\n[controller]\nlaws = [\"tdc\"]\n[faults]\ncontroller_silence_ticks = 300\n{extra}{layout}"
        ),
    )
    .unwrap();
    p.display().to_string()
}

/// CLOCK_MONOTONIC, ns: the clock of `<law>.timing.csv`.
fn monotonic_ns() -> u64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: clock_gettime writes into the struct we own.
    unsafe { libc::clock_gettime(libc::CLOCK_MONOTONIC, &mut ts) };
    ts.tv_sec as u64 * 1_000_000_000 + ts.tv_nsec as u64
}

/// The (k, deadline_ns) of every whole row of `<law>.timing.csv` (a cut last line is skipped).
fn timing_rows(path: &Path) -> Vec<(u64, u64)> {
    let text = std::fs::read_to_string(path).unwrap_or_default();
    text.lines()
        .skip(1)
        .filter_map(|l| {
            let c: Vec<&str> = l.split(',').collect();
            (c.len() == 13).then(|| Some((c[0].parse().ok()?, c[1].parse().ok()?)))?
        })
        .collect()
}

/// The ticks of every whole row of a trace part (header skipped; a cut last line is skipped).
fn part_ticks(path: &Path) -> Vec<u64> {
    let text = std::fs::read_to_string(path).unwrap_or_default();
    let width = text.lines().next().map_or(0, |h| h.split(',').count());
    text.lines()
        .skip(1)
        .filter(|l| l.split(',').count() == width)
        .filter_map(|l| l.split(',').nth(1)?.parse().ok())
        .collect()
}

/// Regression: a realtime run killed at 1.9 s left `trace.tdc.part` and `tdc.timing.csv` at 0
/// bytes: the supervisor finished a tick only once the loop was 8192 ticks (2.5 s) past it.
/// Killed outright (SIGKILL to the whole process group) about 2 s into its loop, a run keeps
/// every tick but those of its last second on disk, counted from tick 0's `deadline_ns`.
#[test]
fn regression_a_killed_run_keeps_all_but_its_last_second() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("killed");
    let cfg = config(tmp.path(), 20.0, "");
    let mut child = spawn_group(&["run", &cfg, "--out", out.to_str().unwrap()]);
    let timing = out.join("tdc.timing.csv");
    let t0 = Instant::now();
    // The supervisor creates the timing file just before START; tick 0 is 10 ms after START.
    while !timing.is_file() {
        assert!(
            t0.elapsed() < Duration::from_secs(30),
            "the loop never started"
        );
        std::thread::sleep(Duration::from_millis(5));
    }
    std::thread::sleep(Duration::from_millis(2200));
    let killed_ns = monotonic_ns();
    // SAFETY: killing the process group this test started.
    unsafe { libc::kill(-(child.id() as i32), libc::SIGKILL) };
    let _ = child.wait();
    std::thread::sleep(Duration::from_millis(100));
    assert!(children_mentioning(out.to_str().unwrap()).is_empty());
    let rows = timing_rows(&timing);
    let Some(&(0, tick0_ns)) = rows.first() else {
        panic!(
            "tdc.timing.csv has no tick 0 ({} bytes) 2.2 s after START",
            std::fs::metadata(&timing).map_or(0, |m| m.len())
        );
    };
    assert!(
        killed_ns > tick0_ns + 1_500_000_000,
        "the loop ran at least 1.5 s before the kill"
    );
    let loop_s = |ns: u64| (ns - tick0_ns) as f64 * 1e-9;
    let (last_k, last_ns) = *rows.last().unwrap();
    assert!(
        last_ns + 1_000_000_000 >= killed_ns,
        "tdc.timing.csv ends at tick {last_k} ({:.3} s of loop), the kill came at {:.3} s",
        loop_s(last_ns),
        loop_s(killed_ns)
    );
    let ticks = part_ticks(&out.join("trace.tdc.part"));
    let last = ticks.last().copied().unwrap_or(0);
    // When tick k ran: its deadline (a loaded host's plant pauses simulated time over its own
    // stalls, so it may be later than tick 0 + k·Ts).
    let last_trace_ns = rows
        .iter()
        .find(|(k, _)| *k == last)
        .map_or(tick0_ns + last * 300_000, |(_, d)| *d);
    assert!(
        !ticks.is_empty() && last_trace_ns + 1_000_000_000 >= killed_ns,
        "trace.tdc.part ends at tick {last} ({:.3} s of loop, {} rows), the kill came at {:.3} s",
        loop_s(last_trace_ns),
        ticks.len(),
        loop_s(killed_ns)
    );
}

/// Whether this process may mount a tmpfs in a private mount namespace (root); if not, says the
/// test is skipped.
fn can_mount(test: &str) -> bool {
    // SAFETY: geteuid has no preconditions.
    let root = unsafe { libc::geteuid() } == 0;
    if !root {
        eprintln!("SKIPPED {test}: needs root to mount a small tmpfs in a private mount namespace");
    }
    root
}

/// Runs `script` (sh) in a private mount namespace with `$DISK` (an empty folder to mount on),
/// `$KEEP` (a folder for what to keep: the namespace goes with the shell), `$CFG` and `$BIN`.
fn in_namespace(tmp: &Path, cfg: &str, script: &str) -> (std::path::PathBuf, std::path::PathBuf) {
    let (disk, keep) = (tmp.join("disk"), tmp.join("keep"));
    std::fs::create_dir(&disk).unwrap();
    std::fs::create_dir(&keep).unwrap();
    let o = std::process::Command::new("unshare")
        .args(["--mount", "--propagation", "private", "sh", "-c", script])
        .env("DISK", &disk)
        .env("KEEP", &keep)
        .env("CFG", cfg)
        .env("BIN", env!("CARGO_BIN_EXE_deltaloop"))
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .expect("unshare runs");
    assert!(
        o.status.success(),
        "cannot mount a tmpfs in a private mount namespace (unshare --mount, as root): {}",
        String::from_utf8_lossy(&o.stderr)
    );
    (disk, keep)
}

/// Runs `cfg` in `mode` on a tmpfs of `from` that shrinks to `to` once the first law's trace
/// part has rows (past the run's check of the free space), so the disk fills mid-run: the
/// run's exit code, the ms from the shrink to its end, its stderr, and the folder its run
/// folder was copied to.
fn shrunk_mid_run(
    tmp: &Path,
    cfg: &str,
    mode: &str,
    from: &str,
    to: &str,
) -> (String, u64, String, std::path::PathBuf) {
    let script = format!(
        r#"
mount -t tmpfs -o size={from} tmpfs "$DISK" || exit 90
timeout 120 "$BIN" run "$CFG" --mode {mode} --out "$DISK/run" 2>"$KEEP/stderr" &
pid=$!
while [ ! -s "$DISK/run/trace.tdc.part" ] && kill -0 $pid 2>/dev/null; do sleep 0.01; done
mount -o remount,size={to} "$DISK" || exit 91
start=$(date +%s%N)
wait $pid
echo $? > "$KEEP/rc"
echo $(( ($(date +%s%N) - start) / 1000000 )) > "$KEEP/ms"
cp -a "$DISK/run" "$KEEP/run" 2>/dev/null || true
"#
    );
    let (_, keep) = in_namespace(tmp, cfg, &script);
    let err = std::fs::read_to_string(keep.join("stderr")).unwrap();
    let rc = std::fs::read_to_string(keep.join("rc")).unwrap();
    let ms: u64 = std::fs::read_to_string(keep.join("ms"))
        .unwrap()
        .trim()
        .parse()
        .unwrap();
    (rc, ms, err, keep)
}

/// Every line of `text` has the header's field count and the text ends with a newline.
fn assert_whole_rows(text: &str, what: &str) {
    let width = text.lines().next().unwrap().split(',').count();
    assert!(text.ends_with('\n'), "{what} ends mid-row");
    for (i, l) in text.lines().enumerate() {
        assert_eq!(l.split(',').count(), width, "{what} line {}: {l}", i + 1);
    }
}

/// Regression: on a full disk, inproc's concurrent laws left `trace.csv` ending mid-row (the
/// first law's part, cut where the disk filled, became `trace.csv`), and runs went on simulating
/// long after the disk was full. Three laws of a 10-minute hold on a tmpfs that shrinks to 16 MiB
/// once they run: the run stops within seconds of the disk filling, with one line naming the file
/// and the full disk, and no file of the folder ends mid-row.
#[test]
fn regression_a_full_disk_cut_inproc_rows_and_did_not_stop_the_run() {
    let test = "regression_a_full_disk_cut_inproc_rows_and_did_not_stop_the_run";
    if !can_mount(test) {
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let cfg = tmp.path().join("three.toml");
    std::fs::write(
        &cfg,
        "name = \"full\"\n[scenario]\npath = \"s1\"\nhold_s = 600.0\n[controller]\nlaws = [\"tdc\", \"tde-is\", \"tdc-is-sta\"]\n",
    )
    .unwrap();
    let (rc, ms, err, keep) =
        shrunk_mid_run(tmp.path(), cfg.to_str().unwrap(), "inproc", "8g", "16m");
    assert_eq!(rc.trim(), "1", "{err}");
    assert_eq!(err.trim().lines().count(), 1, "{err}");
    assert!(err.contains("No space left on device"), "{err}");
    // Filling 16 MiB takes a blink; the three laws' 2 million ticks each take minutes.
    assert!(
        ms < 15_000,
        "the run stopped {ms} ms after the disk shrank: {err}"
    );
    let kept = keep.join("run");
    for e in std::fs::read_dir(&kept).unwrap() {
        let p = e.unwrap().path();
        let name = p.file_name().unwrap().to_string_lossy().into_owned();
        if name.starts_with("trace") {
            let text = std::fs::read_to_string(&p).unwrap();
            if !text.is_empty() {
                assert_whole_rows(&text, &name);
            }
        }
    }
}

/// A lockstep run stops at its first failed write too, not at the end of its scenario (and its
/// `trace.csv` ends with a whole row): a 10-minute hold on a tmpfs that shrinks to 8 MiB once it
/// runs ends within seconds of the disk filling.
#[test]
fn regression_a_full_disk_did_not_stop_a_process_run() {
    let test = "regression_a_full_disk_did_not_stop_a_process_run";
    if !can_mount(test) {
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let cfg = config(tmp.path(), 600.0, "");
    let (rc, ms, err, keep) = shrunk_mid_run(tmp.path(), &cfg, "lockstep", "4g", "8m");
    assert_eq!(rc.trim(), "1", "{err}");
    assert!(err.contains("No space left on device"), "{err}");
    // 8 MiB hold about 11,000 rows of trace and timing: a few seconds of lockstep.
    assert!(
        ms < 30_000,
        "the run stopped {ms} ms after the disk shrank: {err}"
    );
    let trace = std::fs::read_to_string(keep.join("run/trace.csv")).unwrap_or_default();
    if !trace.is_empty() {
        assert_whole_rows(&trace, "trace.csv");
    }
}

/// Regression: `run --hold-s 86400` on a small disk started and filled it (`soak` refuses such a
/// run up front). It is refused before anything is written, in one line naming the run's size
/// and the free space.
#[test]
fn regression_a_day_long_run_on_a_small_disk_is_refused_up_front() {
    let test = "regression_a_day_long_run_on_a_small_disk_is_refused_up_front";
    if !can_mount(test) {
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let script = r#"
mount -t tmpfs -o size=4m tmpfs "$DISK" || exit 90
timeout 60 "$BIN" run configs/s1-nominal.toml --law tdc --mode lockstep --hold-s 86400 --out "$DISK/run" 2>"$KEEP/stderr"
echo $? > "$KEEP/rc"
ls -A "$DISK" > "$KEEP/left"
"#;
    let (_, keep) = in_namespace(tmp.path(), "", script);
    let err = std::fs::read_to_string(keep.join("stderr")).unwrap();
    let rc = std::fs::read_to_string(keep.join("rc")).unwrap();
    assert_eq!(rc.trim(), "1", "{err}");
    assert_eq!(err.trim().lines().count(), 1, "{err}");
    assert!(
        err.contains("scenario.hold_s = 86400") && err.contains("GB free"),
        "{err}"
    );
    let left = std::fs::read_to_string(keep.join("left")).unwrap();
    assert!(left.trim().is_empty(), "left on the disk: {left}");
}
