//! Peers that cheat or forge (docs/protocol.md §12): small misbehaving plants and controllers
//! (`tests/peers/`, on the `deltaloop` Python helper) and the built-in processes under fault
//! injection. Each test names the defect it guards against; the run's record must stay true, or
//! say that it is not.
//!
//! The Python peers need the test venv (`tests/e2e/common/python.rs`: Python ≥ 3.11, PyPI the first
//! time).

use crate::common;

use common::python::{python, root, text};
use common::{FaultKind, RunStatus, deltaloop, outcome, summary};
use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::Output;
use std::time::{Duration, Instant};

/// `<venv python> tests/peers/<script> <args>` as one `--plant-cmd` / `--controller-cmd`.
fn peer(script: &str, args: &str) -> String {
    let cmd = format!(
        "{} {} {args}",
        python().display(),
        root().join("tests/peers").join(script).display()
    );
    assert!(
        !cmd.contains("  "),
        "--*-cmd splits at whitespace: move the checkout ({cmd})"
    );
    cmd
}

/// `deltaloop run <config> --mode <mode> --law tdc --out <tmp>/run <extra…>`: its output and folder.
fn run(tmp: &Path, config: &str, mode: &str, extra: &[&str]) -> (Output, PathBuf) {
    let out = tmp.join("run");
    let mut args = vec![
        "run",
        config,
        "--mode",
        mode,
        "--law",
        "tdc",
        "--out",
        out.to_str().unwrap(),
    ];
    args.extend_from_slice(extra);
    (deltaloop(&args), out)
}

/// S1 in lockstep with `tests/peers/<role>.py <args>` in place of the built-in `role` (`plant` or
/// `controller`).
fn s1_with(tmp: &Path, role: &str, args: &str) -> (Output, PathBuf) {
    let cmd = peer(&format!("{role}.py"), args);
    let flag = format!("--{role}-cmd");
    run(tmp, "configs/s1-nominal.toml", "lockstep", &[&flag, &cmd])
}

/// Writes a scenario file `cfg.toml` into `tmp`.
fn config(tmp: &Path, toml: &str) -> PathBuf {
    let p = tmp.join("cfg.toml");
    std::fs::write(&p, toml).unwrap();
    p
}

/// Starts `deltaloop run <config> --mode lockstep` in the background; its folder.
fn spawn_run(tmp: &Path, toml: &str) -> (std::process::Child, PathBuf) {
    let (cfg, out) = (config(tmp, toml), tmp.join("run"));
    let child = std::process::Command::new(env!("CARGO_BIN_EXE_deltaloop"))
        .args(["run", cfg.to_str().unwrap(), "--mode", "lockstep", "--out"])
        .arg(&out)
        .current_dir(root())
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    (child, out)
}

fn read(p: &Path) -> String {
    std::fs::read_to_string(p).unwrap_or_else(|e| panic!("{}: {e}", p.display()))
}

/// The trace's rows as (reply, drives, arrival_ns).
fn fates(out: &Path) -> Vec<(String, String, String)> {
    let mut r = csv::Reader::from_path(out.join("trace.csv")).unwrap();
    let h = r.headers().unwrap().clone();
    let col = |n: &str| h.iter().position(|c| c == n).unwrap();
    let (reply, drives, arrival) = (col("reply"), col("drives"), col("arrival_ns"));
    r.records()
        .map(|row| {
            let row = row.unwrap();
            (
                row[reply].to_string(),
                row[drives].to_string(),
                row[arrival].to_string(),
            )
        })
        .collect()
}

/// Regression: control messages were believed by their `from` field: a controller could forge
/// START (the run "diverged at tick 0", exit 0), STOP (reported as "stopped by the supervisor")
/// or DIVERGED (its text, with escape codes and a newline, landed verbatim in summary.json and
/// report.md). Now it cannot publish on the supervisor's or the plant's control service, and what
/// it says on its own is believed only if a controller may say it.
#[test]
fn regression_a_controller_cannot_forge_start_stop_or_diverged() {
    let tmp = tempfile::tempdir().unwrap();
    let (o, out) = s1_with(tmp.path(), "controller", "forge");
    let log = read(&out.join("tdc.controller.log"));
    assert!(o.status.success(), "{}\n{log}", text(&o.stderr));
    for refused in [
        "publish on control: refused",
        "publish on control-plant: refused",
        "sent START, STOP, DIVERGED and FAULT",
    ] {
        assert!(log.contains(refused), "{refused}:\n{log}");
    }
    let s = summary(&out);
    let m = &s["laws"]["tdc"];
    assert_eq!(outcome(&s, "tdc"), (RunStatus::Ok, None), "{m}");
    assert_eq!(s["interrupted"], false, "{s}");
    for f in ["summary.json", "report.md"] {
        let t = read(&out.join(f));
        assert!(!t.contains('\u{1b}') && !t.contains("FORGED"), "{f}: {t}");
    }
    common::assert_clean(&out, &s);
}

/// Regression: whoever published on `control` with `from` = plant was the plant. A controller that
/// takes the plant's control service before the plant does (here the plant never joins) now makes
/// the run fail at set-up, naming the process; its READY and DIVERGED are not believed.
#[test]
fn regression_a_process_that_speaks_for_the_plant_is_refused_and_named() {
    let tmp = tempfile::tempdir().unwrap();
    let (plant, ctrl) = (
        peer("plant.py", "idle"),
        peer("controller.py", "speak-for-plant"),
    );
    let t0 = Instant::now();
    let (o, _) = run(
        tmp.path(),
        "configs/s1-nominal.toml",
        "lockstep",
        &["--plant-cmd", &plant, "--controller-cmd", &ctrl],
    );
    let err = text(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(
        err.contains("a process that is not the plant (pid ")
            && err.contains("controller.py speak-for-plant")
            && err.contains("control-plant"),
        "{err}"
    );
    assert!(
        t0.elapsed() < Duration::from_secs(20),
        "refused at once, not after the handshake timeout"
    );
}

/// Regression: the plant took the controller's publish stamp as the arrival time, so a controller
/// stamping its replies with 0 was charged no latency (`arrival_ns` = 0 on every tick) and could
/// not miss its budget. Now every such stamp is replaced by the plant's receive time, flagged,
/// counted in summary.json and named in report.md.
#[test]
fn regression_forged_reply_stamps_are_replaced_by_what_the_plant_observed() {
    let tmp = tempfile::tempdir().unwrap();
    // A Python controller cannot answer within 150 µs: a 1 ms period, a fair layout.
    let cfg = config(
        tmp.path(),
        "name = \"stamps\"\n[scenario]\npath = \"s1\"\n[loop]\nts_s = 1e-3\ntorque_budget_us = 900\n[faults]\ncontroller_silence_ticks = 1000\n[loop.realtime]\nplant_cpu = -1\ncontroller_cpu = -1\nsupervisor_cpu = -1\nplant_priority = 0\ncontroller_priority = 0\nwake_early_us = 0\nlock_memory = false\n",
    );
    let cmd = peer("controller.py", "stamp-zero");
    // How many replies a Python controller gets in within the budget depends on timing: judged
    // on a run the machine left alone; what is said of the stamps holds whatever the host did.
    let test = "regression_forged_reply_stamps_are_replaced_by_what_the_plant_observed";
    common::on_a_noisy_host(test, |n| {
        let dir = tmp.path().join(format!("attempt-{n}"));
        std::fs::create_dir_all(&dir).unwrap();
        forged_stamps_once(&dir, cfg.to_str().unwrap(), &cmd)
    });
}

/// One run of [`regression_forged_reply_stamps_are_replaced_by_what_the_plant_observed`] in `dir`.
fn forged_stamps_once(dir: &Path, cfg: &str, cmd: &str) -> Result<(), String> {
    let (o, out) = run(dir, cfg, "realtime", &["--controller-cmd", cmd]);
    let s = summary(&out);
    let m = &s["laws"]["tdc"];
    let rows = fates(&out);
    // Applied replies the plant reported on: the tick its model failed on (a diverging run)
    // sends no telemetry, so its row has no arrival and its stamp was never looked at.
    let applied: Vec<_> = rows
        .iter()
        .filter(|r| r.0 == "applied" && !r.2.is_empty())
        .collect();
    if applied.is_empty() {
        let why = format!("no reply applied: {}\n{m}", text(&o.stderr));
        return common::judge(common::disturbance(&s, "tdc"), Err(why));
    }
    assert!(
        applied.iter().all(|r| r.2.parse::<u64>().unwrap() > 0),
        "an applied reply stamped 0 was charged no latency"
    );
    assert_eq!(
        m["stamps_replaced"].as_u64(),
        Some(applied.len() as u64),
        "every applied reply carried a stamp of 0: {m}"
    );
    let report = read(&out.join("report.md"));
    assert!(
        report.contains(&format!(
            "{} reply stamp(s) could not be true",
            applied.len()
        )),
        "{report}"
    );
    common::judge(
        common::disturbance(&s, "tdc"),
        (applied.len() > 100).then_some(()).ok_or_else(|| {
            format!(
                "{} replies applied: {}\n{m}",
                applied.len(),
                text(&o.stderr)
            )
        }),
    )
}

/// Regression: a second reply for the same tick was what trace.csv recorded, while the plant had
/// applied the first, and replay then disagreed with the run. Now the first is kept, the others
/// are counted, and the run replays byte for byte.
#[test]
fn regression_a_second_reply_for_a_tick_is_counted_not_recorded() {
    let tmp = tempfile::tempdir().unwrap();
    let (o, out) = s1_with(tmp.path(), "controller", "twice");
    assert!(o.status.success(), "{}", text(&o.stderr));
    let s = summary(&out);
    let m = &s["laws"]["tdc"];
    let ticks = m["ticks"].as_u64().unwrap();
    assert_eq!(m["duplicate_replies"].as_u64(), Some(ticks + 1), "{m}");
    assert!(read(&out.join("report.md")).contains("extra reply(ies)"));
    let r = deltaloop(&["replay", out.to_str().unwrap()]);
    assert!(
        r.status.success() && text(&r.stdout).contains("reproduced byte for byte"),
        "{}{}",
        text(&r.stdout),
        text(&r.stderr)
    );
}

/// Regression: a non-finite torque was recorded as "diverged at tick k", but the loop went on:
/// the drives held for ~2000 more ticks until the robot hit a singularity, and the run ended as
/// a fault (exit 1, "no safe stop possible"). Now the supervisor stops the loop at once, as for
/// any divergence: status diverged at that tick, exit 0.
#[test]
fn regression_a_non_finite_torque_ends_the_run_as_diverged_at_once() {
    let tmp = tempfile::tempdir().unwrap();
    let cfg = config(
        tmp.path(),
        "name = \"nan\"\n[scenario]\npath = \"s1\"\nhold_s = 5.0\n[controller]\nlaws = [\"tdc\"]\n[faults]\ninject = \"nan-torque@500\"\n",
    );
    let (o, out) = run(tmp.path(), cfg.to_str().unwrap(), "lockstep", &[]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    let s = summary(&out);
    let m = &s["laws"]["tdc"];
    assert_eq!(outcome(&s, "tdc"), (RunStatus::Diverged, None), "{m}");
    assert_eq!(m["status_tick"], 500, "{m}");
    assert_eq!(m["diverged_at_tick"], 500, "{m}");
    assert_eq!(m["diverged_reason"], "non-finite torque command", "{m}");
    assert_eq!(s["interrupted"], false, "{s}");
    let ran = s["timing"]["tdc"]["ticks"].as_u64().unwrap();
    assert!(ran < 1500, "the loop ran on to tick {ran}");
    assert!(read(&out.join("tdc.plant.log")).contains("stopped by the supervisor (STOP)"));
    common::assert_clean(&out, &s);
}

/// Regression: a plant that stopped sending telemetry after tick 100 left the run "ok" with the
/// timing of 100 of 2668 ticks, its rows written with invented fates (`applied`, `commanded`), and
/// replay then blamed `arrival_ns`. Now the rows say `unknown`, the run is lost data naming the
/// telemetry, and replay refuses it naming the ticks the run lost.
#[test]
fn regression_a_plant_that_stops_sending_telemetry_is_lost_data_not_ok() {
    let tmp = tempfile::tempdir().unwrap();
    let (o, out) = s1_with(tmp.path(), "plant", "mute-after 100");
    let err = text(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(
        err.contains("lost data") && err.contains("without the plant's telemetry"),
        "{err}"
    );
    let s = summary(&out);
    let m = &s["laws"]["tdc"];
    let n = s["ticks"].as_u64().unwrap();
    assert_eq!(outcome(&s, "tdc"), (RunStatus::LostData, None), "{m}");
    assert_eq!(m["status_tick"], 101, "{m}");
    assert_eq!(m["telemetry_missing"].as_u64(), Some(n - 100), "{m}");
    let rows = fates(&out);
    assert!(rows[..=100].iter().all(|r| r.0 == "applied"));
    assert!(
        rows[101..]
            .iter()
            .all(|r| r.0 == "unknown" && r.1 == "unknown" && r.2.is_empty()),
        "rows without telemetry must not invent fates"
    );
    let r = deltaloop(&["replay", out.to_str().unwrap()]);
    let rerr = text(&r.stderr);
    assert!(!r.status.success(), "{rerr}");
    assert!(
        rerr.contains(&format!("the run lost ticks 101..{n}")),
        "{rerr}"
    );
}

/// Regression: a plant that ended early was reported as "diverged", or as a fault of the
/// controller that never said the plant had exited. Now the run is a fault that says the plant
/// exited with status 0 and after which tick.
#[test]
fn regression_a_plant_that_exits_early_with_status_0_is_named() {
    let tmp = tempfile::tempdir().unwrap();
    let (o, out) = s1_with(tmp.path(), "plant", "quit-after 200");
    let err = text(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    let s = summary(&out);
    let m = &s["laws"]["tdc"];
    let said = format!(
        "the plant exited (status 0) after tick 199 of {}",
        s["ticks"]
    );
    assert!(err.contains(&said), "{err}");
    assert_eq!(
        outcome(&s, "tdc"),
        (RunStatus::Fault, Some(FaultKind::PlantQuit)),
        "{m}"
    );
    assert!(m["diverged_at_tick"].is_null(), "{m}");
}

/// Regression: the built-in controller answered a duplicated state twice (it had no check that
/// a state is newer than the last it answered). A plant that publishes every state again after
/// its reply now gets one reply per tick, and the controller says how many it ignored.
#[test]
fn regression_the_controller_answers_a_duplicated_state_once() {
    let tmp = tempfile::tempdir().unwrap();
    let (o, out) = s1_with(tmp.path(), "plant", "echo-state");
    assert!(o.status.success(), "{}", text(&o.stderr));
    let s = summary(&out);
    let m = &s["laws"]["tdc"];
    assert_eq!(outcome(&s, "tdc"), (RunStatus::Ok, None), "{m}");
    assert_eq!(m["duplicate_replies"], 0, "{m}");
    let log = read(&out.join("tdc.controller.log"));
    assert!(
        log.contains("warning: ignored") && log.contains("not newer than the last one answered"),
        "{log}"
    );
}

/// The built-in children of the run in `out` whose command line names `who`.
fn child(out: &Path, who: &str) -> u32 {
    let t0 = Instant::now();
    loop {
        let pids: Vec<u32> = common::children_mentioning(out.to_str().unwrap())
            .into_iter()
            .filter(|p| {
                std::fs::read(format!("/proc/{p}/cmdline"))
                    .is_ok_and(|c| String::from_utf8_lossy(&c).contains(who))
            })
            .collect();
        if let [p] = pids[..]
            && out.join("tdc.timing.csv").exists()
        {
            return p;
        }
        assert!(t0.elapsed() < Duration::from_secs(20), "no {who} running");
        std::thread::sleep(Duration::from_millis(20));
    }
}

fn signal(pid: u32, sig: i32) {
    // SAFETY: signalling a child of this test's run, found by its command line.
    unsafe { libc::kill(pid as i32, sig) };
}

/// Regression: the controller ignored SIGTERM while blocked waiting for a state (a signal only
/// interrupted the wait, which began again) and ended only at the silence timeout. Now it exits
/// 5 at once, "stopped by SIGTERM". (The plant is frozen with SIGSTOP, so the controller blocks.)
#[test]
fn regression_the_controller_stops_on_sigterm_while_blocked_waiting() {
    let tmp = tempfile::tempdir().unwrap();
    let (mut sup, out) = spawn_run(
        tmp.path(),
        "name = \"term\"\n[scenario]\npath = \"s1\"\nhold_s = 30.0\n[controller]\nlaws = [\"tdc\"]\n[loop]\nsilence_timeout_ms = 20000\n",
    );
    let (plant, ctrl) = (
        child(&out, "deltaloop-plant"),
        child(&out, "deltaloop-controller"),
    );
    signal(plant, libc::SIGSTOP);
    std::thread::sleep(Duration::from_millis(300));
    signal(ctrl, libc::SIGTERM);
    let t0 = Instant::now();
    while Path::new(&format!("/proc/{ctrl}")).exists() && t0.elapsed() < Duration::from_secs(10) {
        std::thread::sleep(Duration::from_millis(10));
    }
    let took = t0.elapsed();
    signal(plant, libc::SIGKILL);
    let _ = sup.wait();
    assert!(
        took < Duration::from_secs(2),
        "the controller took {took:?} to stop on SIGTERM"
    );
    let log = read(&out.join("tdc.controller.log"));
    assert!(log.contains("stopped by SIGTERM"), "{log}");
}

/// Regression: the controller did not watch for STOP during the loop and exited 0 as if the run
/// had completed. Now a Ctrl-C of the run (STOP) ends it with 5, "stopped by the supervisor".
#[test]
fn regression_the_controller_exits_5_on_stop() {
    let tmp = tempfile::tempdir().unwrap();
    let (sup, out) = spawn_run(
        tmp.path(),
        "name = \"stop\"\n[scenario]\npath = \"s1\"\nhold_s = 30.0\n[controller]\nlaws = [\"tdc\"]\n",
    );
    child(&out, "deltaloop-controller");
    // Running, not only spawned (a loaded host may take longer than any fixed wait to START).
    let t0 = Instant::now();
    let part = out.join("trace.tdc.part");
    while std::fs::read_to_string(&part).map_or(0, |t| t.lines().count()) < 2 {
        assert!(
            t0.elapsed() < Duration::from_secs(20),
            "the run did not start"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
    signal(sup.id(), libc::SIGTERM);
    let o = sup.wait_with_output().unwrap();
    assert!(
        text(&o.stderr).contains("interrupted"),
        "{:?} {}",
        o.status,
        text(&o.stderr)
    );
    let log = read(&out.join("tdc.controller.log"));
    assert!(log.contains("stopped by the supervisor (STOP)"), "{log}");
    let plant = read(&out.join("tdc.plant.log"));
    assert!(
        plant.contains("stopped by the supervisor (STOP)"),
        "{plant}"
    );
    let s: Value = summary(&out);
    assert_eq!(outcome(&s, "tdc"), (RunStatus::Interrupted, None), "{s}");
    assert!(s["laws"]["tdc"]["interrupted_at_tick"].as_u64().is_some());
}

use common::{built, c_tdc};

/// The C `tdc` controller (examples/c-controller, on the C ABI) and the C++ one
/// (examples/cpp-controller, on its RAII wrapper) each write the built-in `tdc`'s trace byte for
/// byte in lockstep, leave nothing behind, and refuse a law they do not implement in one line
/// of their own.
#[test]
fn c_and_cpp_controllers_in_lockstep_write_the_builtin_trace_byte_for_byte() {
    let tmp = tempfile::tempdir().unwrap();
    let builtin = tmp.path().join("builtin");
    common::run(
        "configs/s1-nominal.toml",
        "inproc",
        &builtin,
        &["--law", "tdc"],
    );
    let want = std::fs::read(builtin.join("trace.csv")).unwrap();
    let examples = [c_tdc(), built("cpp-controller", "cpp-tdc", "c++")];
    for exe in examples.into_iter().flatten() {
        let name = exe.file_name().unwrap().to_string_lossy().into_owned();
        let dir = tmp.path().join(&name);
        let (o, out) = run(
            &dir,
            "configs/s1-nominal.toml",
            "lockstep",
            &["--controller-cmd", exe.to_str().unwrap()],
        );
        assert!(o.status.success(), "{name}: {}", text(&o.stderr));
        assert!(
            std::fs::read(out.join("trace.csv")).unwrap() == want,
            "{name}'s trace.csv differs from the built-in tdc's"
        );
        common::assert_clean(&out, &summary(&out));
        let (o, _) = run(
            &dir.join("other"),
            "configs/s1-nominal.toml",
            "lockstep",
            &["--controller-cmd", exe.to_str().unwrap(), "--law", "pid"],
        );
        assert!(!o.status.success());
        assert!(
            text(&o.stderr).contains(&format!(
                "{name}: the controller refused the run: this controller implements only tdc, not pid"
            )),
            "{}",
            text(&o.stderr)
        );
    }
}

/// The C plant (examples/c-plant: the library's plant loop around the project's own model) with
/// the built-in controller writes the built-in plant's trace byte for byte in lockstep, with
/// sensor noise (measure is not truth), friction and a payload step; and when the controller
/// falls silent it stops and brakes as the built-in does (same trace, same fault, same speed
/// after the brake).
#[test]
fn a_c_plant_writes_the_builtin_plants_trace_byte_for_byte() {
    let Some(exe) = built("c-plant", "c-plant", "cc") else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let noisy = "name = \"c-plant\"\n[scenario]\npath = \"s1\"\n[plant]\nfriction = true\npayload_step_kg = 0.5\n[sensor]\nencoder_counts_per_rev = 65536\nq_noise_std_rad = 1e-5\nqd_noise_std_rad_s = 1e-3\nseed = 7\n";
    let silent = format!("{noisy}[faults]\ninject = \"stall@1500\"\n");
    for (case, toml, law) in [
        ("noisy", noisy.to_string(), "tdc-is-sta"),
        ("silent", silent, "tdc"),
    ] {
        let dir = tmp.path().join(case);
        std::fs::create_dir_all(&dir).unwrap();
        let cfg = config(&dir, &toml);
        let cfg = cfg.to_str().unwrap();
        let go = |name: &str, extra: &[&str]| {
            let out = dir.join(name);
            let mut args = vec!["run", cfg, "--mode", "lockstep", "--law", law, "--out"];
            args.push(out.to_str().unwrap());
            args.extend_from_slice(extra);
            let o = deltaloop(&args);
            (o, out)
        };
        let (want_o, want) = go("builtin", &[]);
        let (o, out) = go("c", &["--plant-cmd", exe.to_str().unwrap()]);
        assert_eq!(
            o.status.success(),
            want_o.status.success(),
            "{case}: {}",
            text(&o.stderr)
        );
        let trace = |d: &Path| std::fs::read(d.join("trace.csv")).unwrap();
        assert!(
            trace(&out) == trace(&want),
            "{case}: the C plant's trace.csv differs from the built-in plant's"
        );
        let (s, w) = (summary(&out), summary(&want));
        assert_eq!(outcome(&s, law), outcome(&w, law), "{case}");
        if case == "silent" {
            assert_eq!(
                outcome(&s, law).1,
                Some(FaultKind::ControllerSilent),
                "{case}: {s}"
            );
            // The brake ran in the C plant too: the same speed after it, in the same words.
            let braked = |e: &Output| {
                let t = text(&e.stderr);
                t.split("safe stop, max |q̇| = ")
                    .nth(1)
                    .map(|r| r.split(' ').next().unwrap_or("").to_string())
            };
            assert!(braked(&o).is_some(), "{}", text(&o.stderr));
            assert_eq!(braked(&o), braked(&want_o));
        } else {
            assert!(o.status.success(), "{}", text(&o.stderr));
            common::assert_clean(&out, &s);
        }
    }
}

/// In realtime the C controller answers as the built-in does: round trip p50 within 1.5× of the
/// built-in controller's in the same test (runs on either side of it), and no more misses than
/// the worse of them but for a few (judged on undisturbed runs; regression: another
/// test's load on the other CPU during the C run alone made a C p50 of 42 µs against the
/// built-in's 22 µs look like the C library's).
///
/// Regression: "no more misses" at all failed one run in eight on this VM (C 2, built-in 0 and
/// 1): a preemption of a few hundred µs costs a tick and is not a disturbance the record flags
/// (those start at 2 % of the ticks or five in a row), so it lands on any of the three runs.
#[test]
fn a_c_controller_in_realtime_answers_as_fast_as_the_builtin() {
    // About 1e-3 of S1's 2668 ticks: the share of misses the link issue allows a loop on this
    // machine.
    const MISS_ALLOWANCE: u64 = 3;
    let Some(exe) = c_tdc() else { return };
    let tmp = tempfile::tempdir().unwrap();
    common::on_a_noisy_host(
        "a_c_controller_in_realtime_answers_as_fast_as_the_builtin",
        |attempt| {
            let timing = |name: &str, extra: &[&str]| {
                let out = tmp.path().join(format!("{name}-{attempt}"));
                let mut args = vec!["--law", "tdc"];
                args.extend_from_slice(extra);
                let o = common::run_output("configs/s1-nominal.toml", "realtime", &out, &args);
                let s = summary(&out);
                let status = common::assert_every_tick_on_disk(&s, &out, "tdc");
                assert_eq!(
                    o.status.success(),
                    status.is_physical(),
                    "{}",
                    text(&o.stderr)
                );
                (
                    s["timing"]["tdc"].clone(),
                    common::disturbance(&s, "tdc"),
                    status,
                )
            };
            // Built-in, C, built-in: the C run is judged against the built-in runs on either
            // side of it, and a machine whose load changed between those two (another test's
            // burst on the other CPU) disturbed the comparison.
            let (b, b_dist, b_status) = timing("builtin", &[]);
            let (c, c_dist, c_status) = timing("c", &["--controller-cmd", exe.to_str().unwrap()]);
            let (b2, b2_dist, b2_status) = timing("builtin-after", &[]);
            let p50 = |t: &Value| t["round_trip"]["p50_us"].as_f64().unwrap_or(f64::INFINITY);
            let misses = |t: &Value| t["deadline_misses"].as_u64().unwrap_or(u64::MAX);
            let (lo, hi) = (p50(&b).min(p50(&b2)), p50(&b).max(p50(&b2)));
            let load = (hi > 1.3 * lo).then(|| {
                format!(
                    "the built-in's p50 moved from {} to {} µs around the C run",
                    p50(&b),
                    p50(&b2)
                )
            });
            let check = if [b_status, c_status, b2_status]
                .iter()
                .any(|s| *s != RunStatus::Ok)
            {
                Err(format!(
                    "built-in {b_status:?} / {b2_status:?}, C {c_status:?}"
                ))
            } else if p50(&c) > 1.5 * hi {
                Err(format!(
                    "round trip p50: C {} µs, built-in {} and {} µs",
                    p50(&c),
                    p50(&b),
                    p50(&b2)
                ))
            } else if misses(&c) > misses(&b).max(misses(&b2)) + MISS_ALLOWANCE {
                Err(format!(
                    "misses: C {}, built-in {} and {}",
                    misses(&c),
                    misses(&b),
                    misses(&b2)
                ))
            } else {
                Ok(())
            };
            common::judge(b_dist.or(c_dist).or(b2_dist).or(load), check)
        },
    );
}

/// Regression: a C plant whose `truth` or `measure` returned an error was read as zeros: the run
/// ended `ok` with a wrong RMS, or the sensor's failure was filed as the law's divergence. Now a
/// non-zero return stops the loop at that tick as the plant's own fault (PLANT_ERROR, then the
/// safe stop), quoting the message (escaped: one line), and the run is a plant fault.
#[test]
fn regression_c_plant_truth_or_measure_error_is_a_plant_fault() {
    let Some(exe) = common::c_peer("c_plant_faults") else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    for which in ["truth", "measure"] {
        let cmd = format!("{} {which}@200", exe.display());
        let (o, out) = run(
            &tmp.path().join(which),
            "configs/s1-nominal.toml",
            "lockstep",
            &["--plant-cmd", &cmd],
        );
        let err = text(&o.stderr);
        assert_eq!(o.status.code(), Some(1), "{which}: {err}");
        let s = summary(&out);
        let m = &s["laws"]["tdc"];
        assert_eq!(
            outcome(&s, "tdc"),
            (RunStatus::Fault, Some(FaultKind::PlantError)),
            "{which}: {m}"
        );
        assert_eq!(m["status_tick"], 200, "{which}: {m}");
        assert!(m["diverged_at_tick"].is_null(), "{which}: {m}");
        let said = format!(
            "the plant's {which} failed at tick 200: encoder 2: no answer on the CAN bus\\u{{1b}}[0m\\nretry 3 failed (it returned 7)"
        );
        let fault = m["fault"].as_str().unwrap_or_default();
        assert!(fault.contains(&said), "{which}: {fault}");
        assert!(err.contains(&said), "{which}: {err}");
        for f in ["summary.json", "report.md"] {
            let t = read(&out.join(f));
            assert!(!t.contains('\u{1b}'), "{which}: {f}: {t}");
        }
    }
}

/// Regression: a C controller whose step returned an error exited at once, but the plant held
/// the last torque for its whole silence window (2 s in lockstep, 100 ticks in realtime) before
/// the safe stop. The controller now says CONTROLLER_ERROR on its control service and wakes
/// the plant, which stops the loop at that tick naming the error; the run is a controller fault
/// quoting the message.
#[test]
fn regression_a_controller_step_error_stops_the_loop_at_once() {
    let Some(exe) = common::c_peer("c_controller_faults") else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let cmd = format!("{} fail@200", exe.display());
    let (o, out) = run(
        tmp.path(),
        "configs/s1-nominal.toml",
        "lockstep",
        &["--controller-cmd", &cmd],
    );
    assert_eq!(o.status.code(), Some(1), "{}", text(&o.stderr));
    let said = "the controller reported an error at tick 200: the solver did not converge (QP infeasible) (it returned 3)";
    common::assert_step_error_stopped_the_loop_at_once(&out, said);
    let plant = read(&out.join("tdc.plant.log"));
    assert!(
        plant.contains(said) && plant.contains("safe stop"),
        "{plant}"
    );
}

/// The Python helper's controller whose `step` raises: it said nothing to the plant, which held
/// the last torque for its 2 s silence window (lockstep) before the safe stop. It now says
/// CONTROLLER_ERROR with the exception, as `dl_controller_main` does, and the plant stops at
/// that tick at once.
#[test]
fn regression_a_python_step_that_raises_stops_the_loop_at_once() {
    let tmp = tempfile::tempdir().unwrap();
    let cmd = peer("controller.py", "raise-at-200");
    let (o, out) = run(
        tmp.path(),
        "configs/s1-nominal.toml",
        "lockstep",
        &["--controller-cmd", &cmd],
    );
    assert_eq!(o.status.code(), Some(1), "{}", text(&o.stderr));
    let said = "step failed at tick 200: ArithmeticError: the solver did not converge";
    common::assert_step_error_stopped_the_loop_at_once(&out, said);
}
