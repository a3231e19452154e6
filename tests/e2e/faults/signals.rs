//! Signals to the supervisor (SIGTERM, Ctrl-C, SIGHUP, SIGKILL), also during set-up and in a
//! sweep: everything stops, the data is kept, nothing is left that breaks the next run.

use super::*;

#[test]
fn sigterm_ctrl_c_and_sighup_stop_everything_and_keep_the_data() {
    // SIGHUP is the terminal closing: it reaches the whole group, like Ctrl-C (regression: it
    // once killed the children and the supervisor without a word, leaving no trace or summary).
    for sig in [libc::SIGTERM, libc::SIGINT, libc::SIGHUP] {
        let tmp = tempfile::tempdir().unwrap();
        let out = tmp.path().join("run");
        let cfg = config(tmp.path(), 5.0, "");
        // Its own process group, so SIGINT reaches all three like a terminal's Ctrl-C does.
        let child = common::spawn_group(&["run", &cfg, "--out", out.to_str().unwrap()]);
        let pgid = child.id() as i32;
        signal_child(&out, "deltaloop-plant", 0, 400);
        let t0 = Instant::now();
        // SAFETY: signalling the process group we created.
        unsafe { libc::kill(if sig == libc::SIGTERM { pgid } else { -pgid }, sig) };
        let (code, err) = finish(child);
        assert!(
            t0.elapsed() < Duration::from_secs(4),
            "stops within a bounded time: {:?}",
            t0.elapsed()
        );
        assert_eq!(code, Some(130), "signal {sig}: {err}");
        assert!(err.contains("interrupted"), "{err}");
        let s = assert_kept_and_clean(&out);
        assert_eq!(s["interrupted"], true);
        assert_eq!(outcome(&s, "tdc"), (RunStatus::Interrupted, None));
        assert!(s["laws"]["tdc"]["status_tick"].as_u64().unwrap() > 100);
        assert_eq!(
            s["laws"]["tdc"]["status_tick"],
            s["laws"]["tdc"]["interrupted_at_tick"]
        );
        // No comparison with an in-process twin that the same Ctrl-C stops at its first tick.
        let report = std::fs::read_to_string(out.join("report.md")).unwrap();
        assert!(
            report.contains("Not computed: the run was interrupted") && !report.contains("RMS ×"),
            "{report}"
        );
    }
}

#[test]
fn sigkilled_run_leaves_nothing_that_breaks_the_next() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("killed");
    let cfg = config(tmp.path(), 5.0, "");
    let mut child = spawn(&["run", &cfg, "--out", out.to_str().unwrap()]);
    signal_child(&out, "deltaloop-", 0, 400);
    // The run id, from the children's command lines, before anything dies.
    let pid = children_mentioning(out.to_str().unwrap())[0];
    let cmd = String::from_utf8_lossy(&std::fs::read(format!("/proc/{pid}/cmdline")).unwrap())
        .into_owned();
    let run_id = cmd
        .split('\0')
        .skip_while(|a| *a != "--run-id")
        .nth(1)
        .unwrap()
        .to_string();
    // SIGKILL everything: the two children, then the supervisor.
    for p in children_mentioning(out.to_str().unwrap()) {
        // SAFETY: signalling processes we found by their command line.
        unsafe { libc::kill(p as i32, libc::SIGKILL) };
    }
    // SAFETY: as above, our own child.
    unsafe { libc::kill(child.id() as i32, libc::SIGKILL) };
    let _ = child.wait();
    std::thread::sleep(Duration::from_millis(200));
    assert!(children_mentioning(out.to_str().unwrap()).is_empty());
    // Debris exists now (dead nodes of the killed run), unless a concurrent test's run already
    // removed it (every process run starts by removing dead nodes).
    let debris = iceoryx_leftovers(&run_id);
    // The next run removes what is left, says so, and succeeds.
    let next = tmp.path().join("next");
    let o = deltaloop(&[
        "run",
        &config(tmp.path(), 0.0, ""),
        "--mode",
        "lockstep",
        "--out",
        next.to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert!(
        iceoryx_leftovers(&run_id).is_empty(),
        "debris of the killed run is still there"
    );
    // Whoever removed the debris (this run, or a concurrent test's run) reported it; when it was
    // this run, the report names the killed run's nodes.
    if !debris.is_empty() && err.contains("removed stale iceoryx2 resources") {
        assert!(
            err.contains(&run_id),
            "the report names the removed nodes: {err}"
        );
    }
}

#[test]
fn interrupted_sweep_keeps_its_finished_rows() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("sweep");
    let child = spawn(&[
        "sweep",
        "configs/delay-sweep.toml",
        "--out",
        out.to_str().unwrap(),
    ]);
    // Wait for the first finished rows, then SIGTERM.
    let t0 = Instant::now();
    while std::fs::read_to_string(out.join("sweep.csv")).map_or(0, |s| s.lines().count()) < 5 {
        assert!(t0.elapsed() < Duration::from_secs(60), "no rows appeared");
        std::thread::sleep(Duration::from_millis(20));
    }
    // SAFETY: signalling our own child.
    unsafe { libc::kill(child.id() as i32, libc::SIGTERM) };
    let (code, err) = finish(child);
    assert_eq!(code, Some(130), "{err}");
    let mut csv = csv::Reader::from_path(out.join("sweep.csv")).unwrap();
    let status = csv
        .headers()
        .unwrap()
        .iter()
        .position(|h| h == "status")
        .unwrap();
    let statuses: Vec<String> = csv
        .records()
        .map(|r| r.unwrap()[status].to_string())
        .collect();
    let json: Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("sweep.json")).unwrap()).unwrap();
    assert_eq!(
        json.as_array().unwrap().len(),
        statuses.len(),
        "sweep.json holds the same rows"
    );
    // The points running at the stop are marked, not counted as results.
    let finished = statuses.iter().filter(|s| *s != "interrupted").count();
    assert!((4..976).contains(&finished), "{finished} finished rows");
    let report = std::fs::read_to_string(out.join("report.md")).unwrap();
    assert!(
        report.contains("Interrupted") && report.contains(&format!("after {finished} of 976 runs")),
        "{}",
        &report[..200.min(report.len())]
    );
}

/// Regression: Ctrl-C during set-up was ignored: the supervisor still sent START and the loop ran
/// for seconds. Now the handshake stops, STOP releases both children before tick 0, and the run
/// ends as interrupted with no tick run.
#[test]
fn regression_ctrl_c_during_setup_sends_no_start() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("run");
    // A long hold makes the reference slice (and so the handshake) take a while.
    let cfg = config(tmp.path(), 120.0, "");
    let child = common::spawn_group(&["run", &cfg, "--out", out.to_str().unwrap()]);
    let t0 = Instant::now();
    while pids_of(&out, "deltaloop-plant").is_empty() {
        assert!(t0.elapsed() < Duration::from_secs(30), "no plant started");
        std::thread::sleep(Duration::from_millis(1));
    }
    // SAFETY: Ctrl-C to the process group we created.
    unsafe { libc::kill(-(child.id() as i32), libc::SIGINT) };
    let t1 = Instant::now();
    let (code, err) = finish(child);
    assert_eq!(code, Some(130), "{err}");
    assert!(t1.elapsed() < Duration::from_secs(4), "{:?}", t1.elapsed());
    let plant_log = std::fs::read_to_string(out.join("tdc.plant.log")).unwrap_or_default();
    assert!(plant_log.contains("before start"), "plant: {plant_log}");
    let s = summary(&out);
    assert_eq!(s["interrupted"], true);
    assert_eq!(outcome(&s, "tdc"), (RunStatus::Interrupted, None), "{s}");
    assert_eq!(s["laws"]["tdc"]["status_tick"], 0, "{s}");
    assert!(children_mentioning(out.to_str().unwrap()).is_empty());
}

/// Regression: a child killed during set-up left half-created iceoryx2 nodes that no later run
/// removed, and every later run printed iceoryx2's "No config file was loaded" warning.
#[test]
fn regression_child_killed_during_setup_leaves_no_debris() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("run");
    let cfg = config(tmp.path(), 0.0, "");
    let child = spawn(&["run", &cfg, "--out", out.to_str().unwrap()]);
    let t0 = Instant::now();
    let (pid, run_id) = loop {
        if let Some(&p) = pids_of(&out, "deltaloop-plant").first() {
            let cmd = std::fs::read(format!("/proc/{p}/cmdline")).unwrap_or_default();
            let args: Vec<String> = String::from_utf8_lossy(&cmd)
                .split('\0')
                .map(str::to_string)
                .collect();
            if let Some(i) = args.iter().position(|a| a == "--run-id") {
                break (p, args[i + 1].clone());
            }
        }
        assert!(t0.elapsed() < Duration::from_secs(20), "no plant started");
        std::thread::sleep(Duration::from_micros(500));
    };
    // SAFETY: killing the plant we found by its command line, mid set-up.
    unsafe { libc::kill(pid as i32, libc::SIGKILL) };
    let (code, err) = finish(child);
    assert_eq!(code, Some(1), "{err}");
    assert_eq!(err.trim().lines().count(), 1, "{err}");
    assert!(err.contains("plant"), "{err}");
    assert!(common::iceoryx_leftovers(&run_id).is_empty(), "{err}");
    // The next run starts clean and quiet.
    let out2 = tmp.path().join("next");
    let o = deltaloop(&[
        "run",
        &cfg,
        "--mode",
        "lockstep",
        "--out",
        out2.to_str().unwrap(),
    ]);
    let err2 = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err2}");
    assert!(!err2.contains("No config file"), "{err2}");
}
