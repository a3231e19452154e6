//! A process killed, panicking, diverging, rejecting torque or outliving the run: the other is
//! stopped, the fault reported with its cause.

use super::*;

#[test]
fn controller_killed_plant_holds_then_brakes_supervisor_reports() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("run");
    let cfg = config(tmp.path(), 5.0, "");
    let child = spawn(&["run", &cfg, "--out", out.to_str().unwrap()]);
    // In the hold phase after the motion (t > 0.8 s): the held torque holds the robot, so the
    // safe stop is a real stop; mid-motion a 300 ms hold would drift into a singularity.
    signal_child(&out, "deltaloop-controller", libc::SIGKILL, 1500);
    let (code, err) = finish(child);
    assert_eq!(code, Some(1), "{err}");
    assert_eq!(err.trim().lines().count(), 1, "one-line cause: {err}");
    for needle in [
        "controller was killed (SIGKILL)",
        "no torque within the budget for 300 consecutive ticks",
        "braked for 100 ms",
        "safe stop",
        "the supervisor saw the controller exit",
    ] {
        assert!(err.contains(needle), "missing {needle:?} in: {err}");
    }
    let s = assert_kept_and_clean(&out);
    let m = &s["laws"]["tdc"];
    assert_eq!(
        outcome(&s, "tdc"),
        (RunStatus::Fault, Some(FaultKind::ControllerKilled)),
        "{m}"
    );
    assert_eq!(m["completed"], false);
    assert!(m["status_tick"].as_u64().unwrap() > 1000, "{m}");
    assert_eq!(m["status_tick"], m["fault_at_tick"], "{m}");
    assert!(
        std::fs::read_to_string(out.join("report.md"))
            .unwrap()
            .contains("**fault** at tick")
    );
}

#[test]
fn plant_killed_controller_is_stopped_and_fault_reported() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("run");
    let cfg = config(tmp.path(), 5.0, "");
    let child = spawn(&["run", &cfg, "--out", out.to_str().unwrap()]);
    let t0 = Instant::now();
    signal_child(&out, "deltaloop-plant", libc::SIGKILL, 400);
    let (code, err) = finish(child);
    assert!(
        t0.elapsed() < Duration::from_secs(5),
        "bounded: {:?}",
        t0.elapsed()
    );
    assert_eq!(code, Some(1), "{err}");
    assert!(
        err.contains("plant was killed (SIGKILL)")
            && err.contains("the supervisor saw the plant exit"),
        "{err}"
    );
    let s = assert_kept_and_clean(&out);
    assert_eq!(
        outcome(&s, "tdc"),
        (RunStatus::Fault, Some(FaultKind::PlantKilled))
    );
}

#[test]
fn injected_panic_and_stall_are_faults_with_their_cause() {
    // Injected in the hold phase after the motion (tick 3000 > 2667), where holding the last
    // torque holds the robot; mid-motion a long hold can drift into a singularity margin.
    for (inject, kind) in [
        ("panic@3000", FaultKind::ControllerPanicked),
        ("stall@3000", FaultKind::ControllerSilent),
    ] {
        let tmp = tempfile::tempdir().unwrap();
        let out = tmp.path().join("run");
        let cfg = config(
            tmp.path(),
            1.0,
            &format!("[faults]\ninject = \"{inject}\"\n"),
        );
        let o = deltaloop(&["run", &cfg, "--out", out.to_str().unwrap()]);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(1), "{inject}: {err}");
        assert!(err.contains("safe stop"), "{inject}: {err}");
        let s = assert_kept_and_clean(&out);
        assert_eq!(
            outcome(&s, "tdc"),
            (RunStatus::Fault, Some(kind)),
            "{inject}"
        );
        // The 300th consecutive missing torque ends the hold window: tick 3299 if the controller
        // answered every tick up to 2999, earlier if misses just before the injection joined the
        // run (a loaded host once made that 128 ticks earlier); never later. What holds whatever
        // the load: the 299 ticks before the fault are all missed (the fault tick, the 300th
        // miss, is where the loop stopped: it has no row).
        let tick = s["laws"]["tdc"]["fault_at_tick"].as_u64().unwrap();
        assert!(
            (3000..=3299).contains(&tick),
            "{inject}: fault at tick {tick}"
        );
        assert_eq!(
            held_ticks(&out.join("trace.csv"), tick - 299..=tick),
            299,
            "{inject}: fault at tick {tick}"
        );
        assert!(err.contains(&format!("fault at tick {tick}")), "{err}");
        if inject.starts_with("stall") {
            assert_stalled_rows_are_honest(&out.join("trace.csv"), 3000);
        }
    }
}

/// How many ticks in `ticks` trace.csv records with no torque applied in time (the plant counts
/// each towards its silence window).
fn held_ticks(trace: &Path, ticks: std::ops::RangeInclusive<u64>) -> usize {
    let mut r = csv::Reader::from_path(trace).unwrap();
    let h = r.headers().unwrap().clone();
    let col = |name: &str| h.iter().position(|c| c == name).unwrap();
    let (k, reply) = (col("k"), col("reply"));
    r.records()
        .map(Result::unwrap)
        // The plant counts every tick whose torque did not arrive in time: no reply (`missed`),
        // one for a newer state (`skipped`), or one past the budget (`late`; regression: a
        // loaded host made tick 2999's reply late, and the window held 298 `missed` rows).
        .filter(|row| {
            ticks.contains(&row[k].parse().unwrap())
                && matches!(&row[reply], "missed" | "late" | "skipped")
        })
        .count()
}

/// Regression: trace.csv once filled a tick the controller never answered with the next state's
/// τᵃ and the last reply's s, N̂ and u. Every row from the stall on must say `missed`, leave the
/// controller's columns empty, and show that the drives held; rows before it carry real replies.
fn assert_stalled_rows_are_honest(trace: &Path, stall: u64) {
    let mut r = csv::Reader::from_path(trace).unwrap();
    let h = r.headers().unwrap().clone();
    let col = |name: &str| h.iter().position(|c| c == name).unwrap();
    let (k, tau, s, n_hat) = (col("k"), col("tau_1"), col("s_1"), col("n_hat_1"));
    let (reply, drives) = (col("reply"), col("drives"));
    let (mut before, mut after) = (0, 0);
    for row in r.records() {
        let row = row.unwrap();
        let tick: u64 = row[k].parse().unwrap();
        if tick >= stall {
            after += 1;
            assert_eq!(&row[reply], "missed", "tick {tick}");
            assert_eq!(&row[drives], "held", "tick {tick}");
            for c in [tau, s, n_hat] {
                assert!(
                    row[c].is_empty(),
                    "tick {tick}: column {} = {}",
                    &h[c],
                    &row[c]
                );
            }
        } else {
            // Before the stall a loaded machine may miss a few ticks: whatever the row says, its
            // controller columns agree with it.
            let answered = matches!(&row[reply], "applied" | "late");
            assert_eq!(
                !row[tau].is_empty(),
                answered,
                "tick {tick}: {}",
                &row[reply]
            );
            assert_eq!(!row[n_hat].is_empty(), answered, "tick {tick}");
            before += usize::from(&row[reply] == "applied");
        }
    }
    assert!(
        before > 2000 && after > 200,
        "{before} applied before, {after} rows after the stall"
    );
}

#[test]
fn over_limit_torque_is_rejected_per_config_and_counted() {
    // The paper preset's STA limit cycle commands beyond ±100 N m: with `reject` the plant holds.
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("run");
    let p = tmp.path().join("rej.toml");
    std::fs::write(&p, "[scenario]\npath = \"s1\"\n[plant]\nfriction = true\n[controller]\npreset = \"paper\"\nlaws = [\"tdc-is-sta\"]\n[faults]\ntorque_limit = \"reject\"\n").unwrap();
    let o = deltaloop(&[
        "run",
        p.to_str().unwrap(),
        "--mode",
        "inproc",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(o.status.success());
    let m = &summary(&out)["laws"]["tdc-is-sta"];
    assert!(
        m["rejected_count"].as_u64().unwrap() > 0 && m["clamp_count"] == 0,
        "{m}"
    );
    assert!(
        std::fs::read_to_string(out.join("report.md"))
            .unwrap()
            .contains("the plant rejected")
    );
}

/// Regression: a controller that outlived the run (it kept running after the plant's final
/// state) was filed `hung` with a cause naming the plant ("the supervisor saw the plant exit …").
/// It is the controller's fault, and the cause says so first.
#[test]
fn regression_a_controller_that_outlives_the_run_is_named() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("run");
    let cfg = tmp.path().join("cfg.toml");
    let ctrl = env!("CARGO_BIN_EXE_deltaloop-controller");
    // The built-in controller, then 60 s more of its process (sh runs it, then sleeps).
    std::fs::write(
        &cfg,
        format!(
            "name = \"outlives\"\n[scenario]\npath = \"s1\"\nhold_s = 0.0\n[controller]\nlaws = [\"tdc\"]\ncommand = [\"sh\", \"-c\", \"\\\"$0\\\" \\\"$@\\\"; sleep 60\", \"{ctrl}\"]\n"
        ),
    )
    .unwrap();
    let t0 = Instant::now();
    let o = deltaloop(&[
        "run",
        cfg.to_str().unwrap(),
        "--mode",
        "lockstep",
        "--out",
        out.to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(t0.elapsed() < Duration::from_secs(40), "{err}");
    let s = summary(&out);
    assert_eq!(
        outcome(&s, "tdc"),
        (RunStatus::Fault, Some(FaultKind::ControllerHung)),
        "{err}"
    );
    let cause = s["laws"]["tdc"]["fault"].as_str().unwrap_or_default();
    assert!(
        cause.starts_with("the controller did not exit after the plant's final state"),
        "{cause}"
    );
    assert!(!cause.contains("saw the plant exit"), "{cause}");
    // Every tick ran: the trace has ticks 0..=N, N + 1 the final state's tick the fault names.
    let rows = std::fs::read_to_string(out.join("trace.csv"))
        .unwrap()
        .lines()
        .count()
        - 1;
    assert_eq!(
        Some(rows as u64),
        s["laws"]["tdc"]["fault_at_tick"].as_u64(),
        "{s}"
    );
}

/// Regression: a realtime soak whose robot diverged (tracking error above 0.5 rad) after two
/// minutes ran on for the rest of its hour, recording nothing. Now the supervisor stops the loop
/// at the divergence: the plant brakes, the run says where it diverged, as inproc does.
#[test]
fn regression_a_diverged_process_run_stops_the_loop() {
    let tmp = tempfile::tempdir().unwrap();
    let run = |mode: &str| {
        let out = tmp.path().join(mode);
        // S2, paper preset, tdc, d = 8: diverges within the motion (tests/e2e/delay_injection.rs);
        // the 300 s hold is 10^6 ticks the loop must not run.
        let o = deltaloop(&[
            "run",
            "configs/paper/s2-fast.toml",
            "--mode",
            mode,
            "--law",
            "tdc",
            "--transport-delay",
            "8",
            "--hold-s",
            "300",
            "--out",
            out.to_str().unwrap(),
        ]);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        (summary(&out), out)
    };
    let (inproc, _) = run("inproc");
    let (lockstep, out) = run("lockstep");
    // Regression: a run that diverged by the tracking rule could not be replayed (its last row
    // has an applied reply and no arrival); it replays byte for byte.
    common::assert_replays(&out);
    let tick = inproc["laws"]["tdc"]["diverged_at_tick"].as_u64().unwrap();
    let m = &lockstep["laws"]["tdc"];
    assert_eq!(
        outcome(&lockstep, "tdc"),
        (RunStatus::Diverged, None),
        "{m}"
    );
    assert_eq!(m["status_tick"].as_u64(), Some(tick), "{m}");
    assert_eq!(m["diverged_at_tick"].as_u64(), Some(tick), "{m}");
    let ran = lockstep["timing"]["tdc"]["ticks"].as_u64().unwrap();
    assert!(
        ran < tick + 50_000,
        "the loop ran {ran} ticks after diverging at {tick}"
    );
    let plant_log = std::fs::read_to_string(out.join("tdc.plant.log")).unwrap();
    assert!(
        plant_log.contains("stopped by the supervisor") && plant_log.contains("safe stop"),
        "{plant_log}"
    );
    assert!(children_mentioning(out.to_str().unwrap()).is_empty());
}
