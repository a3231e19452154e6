//! A stalled, held-up or killed bridge: the run replays, recovers or says what it lost.

use super::*;

/// The pid of `parent`'s child whose command line says `deltaloop-bridge near`, within 30 s.
fn near_bridge_of(parent: u32) -> i32 {
    let t0 = std::time::Instant::now();
    loop {
        for e in std::fs::read_dir("/proc").unwrap().flatten() {
            let Ok(pid) = e.file_name().to_string_lossy().parse::<i32>() else {
                continue;
            };
            let stat = std::fs::read_to_string(e.path().join("stat")).unwrap_or_default();
            // The parent is the second field after the command's closing parenthesis.
            let ppid = stat
                .rsplit_once(") ")
                .and_then(|(_, rest)| rest.split(' ').nth(1))
                .and_then(|p| p.parse::<u32>().ok());
            let cmd = std::fs::read(e.path().join("cmdline")).unwrap_or_default();
            if ppid == Some(parent) && text(&cmd).contains("deltaloop-bridge\0near") {
                return pid;
            }
        }
        assert!(
            t0.elapsed() < Duration::from_secs(30),
            "no near bridge under {parent}"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// Regression: a bridge held up for 30–300 ms mid-run (SIGSTOP: its host did not run it) left
/// a record that `replay` could not reproduce. The near side sent the plant's backlog of states
/// on at once, the far controller answered each, and the burst of replies overflowed the near
/// side's socket: states the controller had answered were recorded as unanswered ("ok, lost 0",
/// then "trace.csv differs"). And a late reply to the tick the plant stopped at (the controller
/// silence that followed) made a row with `reply` unknown, which the replay refused as a lost
/// tick. Each bridge of each role in turn is stalled five times for 200 ms: the run replays byte for byte,
/// or the replay refuses exactly the ticks the summary counts as lost. On the relay path the stall
/// reaches the loop; on the direct path (the loop's messages do not pass a bridge) it must not:
/// only the record's copies wait.
#[test]
fn regression_a_stalled_bridge_run_replays_or_says_what_it_lost() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    for (role, stalled, path) in [
        ("controller", "near", "relay"),
        ("controller", "far", "relay"),
        ("plant", "near", "relay"),
        ("plant", "far", "relay"),
        ("controller", "near", "direct"),
    ] {
        // A loaded host may start the loop only after the stalls: such a run tests nothing, and
        // is run again.
        let name = format!("stalled bridge: {role} remote, {stalled} stalled, {path} path");
        common::on_a_noisy_host(&name, |_| {
            let (tmp, cfg, key, ep) = s1_with_key();
            let out = tmp.path().join("run");
            let remote = format!("--{role}-remote");
            let s = |p: &Path| p.to_str().unwrap().to_string();
            let args = [
                "run",
                &s(&cfg),
                "--mode",
                "realtime",
                &remote,
                &ep,
                "--link-key",
                &s(&key),
                "--hold-s",
                "4",
                "--link-path",
                path,
                "--out",
                &s(&out),
            ];
            let run = common::spawn(&args);
            let near = near_bridge_of(run.id());
            let far_root = tmp.path().join("far-root");
            let join = join_as(&ep, role, &key, &far_root);
            // `join` exec'd the far bridge: its pid is the far bridge's.
            let pid = if stalled == "near" {
                near
            } else {
                join.id() as i32
            };
            let log = out.join(format!("tdc.{role}.log"));
            let t0 = std::time::Instant::now();
            while !std::fs::read_to_string(&log).is_ok_and(|l| l.contains("joined")) {
                assert!(t0.elapsed() < Duration::from_secs(60), "nobody joined");
                std::thread::sleep(Duration::from_millis(20));
            }
            // START, and some of the loop; then, five times, the bridge's host does not run it
            // for 200 ms (one stall lost replies in about a third of the runs before the fix).
            std::thread::sleep(Duration::from_millis(600));
            for _ in 0..5 {
                std::thread::sleep(Duration::from_millis(500));
                // SAFETY: a process of this test's (the run's child, or join's exec).
                unsafe { libc::kill(pid, libc::SIGSTOP) };
                std::thread::sleep(Duration::from_millis(200));
                unsafe { libc::kill(pid, libc::SIGCONT) };
            }
            let (o, _) = finish_pair(run, join, &far_root);
            let case = format!("{role} remote, {stalled} bridge stalled, {path} path");
            let trace = rows(&out.join("trace.csv"));
            assert!(!trace.is_empty(), "{case}: no trace: {}", text(&o.stderr));
            // On the relay path the stall hit the loop: a stretch of ticks the plant got no reply
            // for in time (each stall is ≈ 667 ticks). On the direct path it did not.
            let longest = trace
                .split(|r| r["reply"] == "applied")
                .map(<[_]>::len)
                .max()
                .unwrap_or(0);
            if path == "relay" && longest < 300 {
                return Err(format!("{case}: no stall in the trace ({longest})"));
            }
            if path == "direct" {
                assert!(
                    longest < 300,
                    "{case}: the bridge's stall reached the loop ({longest})"
                );
            }
            let whole = replays_or_names_what_it_lost(&case, &out, &tmp.path().join("replay"));
            assert!(whole || path == "relay", "{case}: the record lost ticks");
            Ok(())
        });
    }
}

/// `deltaloop replay OUT --out REPLAY`: the run reproduces byte for byte (true), or the replay
/// refuses it for ticks the record says it lost, and names (false). Anything else fails `case`.
fn replays_or_names_what_it_lost(case: &str, out: &Path, replay: &Path) -> bool {
    let s = |p: &Path| p.to_str().unwrap().to_string();
    let r = common::deltaloop(&["replay", &s(out), "--out", &s(replay)]);
    let said = text(&r.stdout) + &text(&r.stderr);
    eprintln!("{case}: {}", said.trim_end());
    if r.status.success() {
        assert!(said.contains("reproduced byte for byte"), "{case}: {said}");
        return true;
    }
    // Refused: only for ticks the record says it lost, and names.
    let lost = said
        .split_once("the run lost ticks ")
        .and_then(|(_, t)| t.split_once(' '))
        .and_then(|(range, _)| range.split_once(".."))
        .and_then(|(a, b)| Some((a.parse::<u64>().ok()?, b.parse::<u64>().ok()?)));
    let Some((first, last)) = lost else {
        panic!("{case}: the replay differs from the record: {said}");
    };
    let law = &summary(out)["laws"]["tdc"];
    let counted = ["lost_ticks", "telemetry_missing", "replies_lost"]
        .iter()
        .map(|k| law[k].as_u64().unwrap_or(0))
        .sum::<u64>();
    assert!(
        law["status"] != "ok" && counted > last - first,
        "{case}: replay refused ticks {first}..{last}, the summary: {law}"
    );
    let named =
        law["lost_data"].as_str().unwrap_or("").to_string() + law["reason"].as_str().unwrap_or("");
    assert!(named.contains(&format!("tick {first}")), "{case}: {law}");
    false
}

/// Regression: more than three reply datagrams in a row lost on the link (a burst, here the
/// emulated `[link] loss` of 30 %) lost replies the far controller had computed: the record
/// filed those ticks as `missed`, the replay's controller did not step on them, and its torque
/// differed from the next answered tick on ("trace.csv differs", while the summary said the run
/// was fine). The near bridge now sees the hole in the replies' numbers and recalls it from the
/// far side's ring over the control connection, or tells the supervisor which ticks' replies are
/// unknown: the run replays byte for byte, or the replay refuses exactly the ticks the summary
/// counts as lost.
#[test]
fn regression_a_burst_of_lost_replies_is_recovered_or_recorded_as_lost() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let (tmp, cfg, key, ep) = s1_with_key();
    let out = tmp.path().join("run");
    let s = |p: &Path| p.to_str().unwrap().to_string();
    let args = [
        "run",
        &s(&cfg),
        "--mode",
        "realtime",
        "--controller-remote",
        &ep,
        "--link-key",
        &s(&key),
        "--link-loss",
        "0.3",
        "--link-seed",
        "7",
        "--hold-s",
        "1",
        "--link-path",
        "relay",
        "--out",
        &s(&out),
    ];
    let run = common::spawn(&args);
    let far_root = tmp.path().join("far-root");
    let join = join_as(&ep, "controller", &key, &far_root);
    let (o, j) = finish_pair(run, join, &far_root);
    let case = "30 % of the link's datagrams lost";
    assert!(
        out.join("trace.csv").is_file(),
        "{case}: no trace: {}",
        text(&o.stderr)
    );
    let whole = replays_or_names_what_it_lost(case, &out, &tmp.path().join("replay"));
    // The loss made bursts beyond the copies, and the near bridge recalled them.
    let log = std::fs::read_to_string(out.join("tdc.controller.log")).unwrap_or_default();
    let beyond = log
        .split_once(" lost beyond its copies (")
        .and_then(|(before, after)| {
            let lost = before.rsplit(' ').next()?.parse::<u64>().ok()?;
            let recalled = after.split(' ').next()?.parse::<u64>().ok()?;
            Some((lost, recalled))
        });
    let Some((lost, recalled)) = beyond else {
        panic!("{case}: the near bridge's link line is missing: {log}");
    };
    assert!(lost > 0, "{case}: no burst beyond the copies: {log}");
    assert!(
        recalled == lost || !whole,
        "{case}: {lost} lost beyond the copies, {recalled} recalled, and the run replayed whole"
    );
    eprintln!(
        "{case}: {lost} repl(ies) lost beyond the copies, {recalled} recalled; join: {}",
        text(&j.stderr).trim_end()
    );
    // The direct path: the same loss on the plant's and the controller's own sockets; the record
    // takes every reply from the far side over the control connection, so the run replays whole.
    let out = tmp.path().join("direct");
    let mut args = args.map(str::to_string);
    let n = args.len();
    (args[n - 3], args[n - 1]) = ("direct".into(), s(&out));
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    let run = common::spawn(&args);
    let join = join_as(&ep, "controller", &key, &far_root);
    let (o, _) = finish_pair(run, join, &far_root);
    let case = "30 % lost, direct path";
    assert!(
        out.join("trace.csv").is_file(),
        "{case}: {}",
        text(&o.stderr)
    );
    let plant_log = std::fs::read_to_string(out.join("tdc.plant.log")).unwrap_or_default();
    assert!(
        replays_or_names_what_it_lost(case, &out, &tmp.path().join("replay-direct")),
        "{case}: the record lost replies: {plant_log}"
    );
}

/// Regression (`--plant-remote`): the near bridge moved each state's stamps onto this host's
/// clock by that state's own delay, so after a 200 ms stall of the near bridge every later
/// deadline moved by the stall, the controller's schedule followed, and no reply was applied
/// again (300 missed, 3 skipped, 1 late, repeating) until the silence fault. The stamps move by
/// the clocks' offset: the loop applies replies again after the stall. Judged against the same
/// run before the stall, so a host that disturbs the whole run says nothing (run again).
#[test]
fn regression_a_remote_plant_loop_recovers_after_a_near_bridge_stall() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    common::on_a_noisy_host(
        "a_remote_plant_loop_recovers_after_a_near_bridge_stall",
        |_| {
            let (tmp, cfg, key, ep) = s1_with_key();
            let out = tmp.path().join("run");
            let s = |p: &Path| p.to_str().unwrap().to_string();
            let args = [
                "run",
                &s(&cfg),
                "--mode",
                "realtime",
                "--plant-remote",
                &ep,
                "--link-key",
                &s(&key),
                "--hold-s",
                "4",
                "--link-path",
                "relay",
                "--out",
                &s(&out),
            ];
            let run = common::spawn(&args);
            let near = near_bridge_of(run.id());
            let far_root = tmp.path().join("far-root");
            let join = join_as(&ep, "plant", &key, &far_root);
            let log = out.join("tdc.plant.log");
            let t0 = std::time::Instant::now();
            while !std::fs::read_to_string(&log).is_ok_and(|l| l.contains("joined")) {
                assert!(t0.elapsed() < Duration::from_secs(60), "nobody joined");
                std::thread::sleep(Duration::from_millis(20));
            }
            // Three stalls of 200 ms, 0.8 s apart (one left the loop unrecovered in about half
            // the runs before the fix).
            std::thread::sleep(Duration::from_millis(1000));
            for _ in 0..3 {
                // SAFETY: the run's child, the near bridge.
                unsafe { libc::kill(near, libc::SIGSTOP) };
                std::thread::sleep(Duration::from_millis(200));
                unsafe { libc::kill(near, libc::SIGCONT) };
                std::thread::sleep(Duration::from_millis(600));
            }
            let (o, _) = finish_pair(run, join, &far_root);
            let trace = rows(&out.join("trace.csv"));
            assert!(!trace.is_empty(), "no trace: {}", text(&o.stderr));
            let applied: Vec<bool> = trace.iter().map(|r| r["reply"] == "applied").collect();
            let share =
                |r: &[bool]| r.iter().filter(|a| **a).count() as f64 / r.len().max(1) as f64;
            // Before the first stall (the first 0.9 s of the loop), and the last second of the run,
            // which must have come (S1 + 4 s hold: 16,001 ticks).
            let before = share(&applied[..3000.min(applied.len())]);
            let last = share(&applied[applied.len().saturating_sub(3333)..]);
            eprintln!(
                "{} ticks; {before:.2} applied before the stalls, {last:.2} in the last second",
                applied.len()
            );
            if before < 0.5 {
                return Err(format!(
                    "the loop was already disturbed: {before:.2} applied before"
                ));
            }
            assert!(
                applied.len() == 16_001 && last > 0.5,
                "{before:.2} of the replies applied before the stalls, {last:.2} in the last second of {} ticks: {}",
                applied.len(),
                text(&o.stderr)
            );
            Ok(())
        },
    );
}

/// Regression: with `--controller-remote`, a near bridge its host held up for about 3 s lost
/// reply copies without a word: the supervisor had finished those ticks (or its queue had
/// overflowed) before the copies came, so the run said `ok`, `replies_lost` 0, hundreds of rows
/// "missed" that the far controller had answered, and `replay` "differs at tick 3145". The near
/// bridge knows when it was held up past what the record can wait for, and tells the
/// supervisor which ticks' replies it cannot file (REPLIES_LOST): the run is `lost_data` with
/// them counted, and the replay refuses exactly those ticks, as with a stalled `--plant-remote`.
/// About 15 s: `cargo test --test e2e link_loopback::regression_a_near_bridge_held_up_3_s -- --ignored`.
#[test]
#[ignore = "a 3 s stall in a 7 s run: see docs/guide/failure-behaviour.md"]
fn regression_a_near_bridge_held_up_3_s_loses_no_reply_copy_silently() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let RemoteController {
        tmp,
        out,
        run,
        near,
        join,
        far_root,
        log,
    } = remote_controller_started(&["--hold-s", "6"]);
    std::thread::sleep(Duration::from_millis(1000));
    // SAFETY: the run's child, the near bridge.
    unsafe { libc::kill(near, libc::SIGSTOP) };
    std::thread::sleep(Duration::from_millis(3000));
    unsafe { libc::kill(near, libc::SIGCONT) };
    let (o, _) = finish_pair(run, join, &far_root);
    let law = &summary(&out)["laws"]["tdc"];
    eprintln!("{law}\n{}", text(&o.stderr));
    assert_eq!(law["status"], "lost_data", "{law}");
    assert!(law["replies_lost"].as_u64().unwrap_or(0) > 0, "{law}");
    let whole =
        replays_or_names_what_it_lost("near bridge held up 3 s", &out, &tmp.path().join("replay"));
    assert!(!whole, "the replay reproduced a run that lost replies");
    let log = std::fs::read_to_string(&log).unwrap();
    assert!(log.contains("had finished those ticks"), "{log}");
}

/// Regression: a near bridge killed with -9 in a `--controller-remote` run was reported as
/// "the controller was killed (SIGKILL)", though the controller on the other host was fine.
/// The run's reason names the bridge.
#[test]
fn regression_a_killed_near_bridge_is_named_not_the_controller() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let RemoteController {
        tmp: _tmp,
        out,
        run,
        near,
        join,
        far_root,
        ..
    } = remote_controller_started(&[]);
    std::thread::sleep(Duration::from_millis(300));
    // SAFETY: the run's child, the near bridge.
    unsafe { libc::kill(near, libc::SIGKILL) };
    let (o, _) = finish_pair(run, join, &far_root);
    let law = &summary(&out)["laws"]["tdc"];
    let reason = law["reason"].as_str().unwrap_or("");
    assert!(
        reason.contains("near bridge") && reason.contains("SIGKILL"),
        "{law}\n{}",
        text(&o.stderr)
    );
    assert!(!reason.contains("the controller was killed"), "{reason}");
}

/// A realtime S1 run with its controller joined from "the other host" (loopback), once the loop
/// runs on the direct path: the run, its near bridge's pid, the join and where things are.
struct RemoteController {
    tmp: tempfile::TempDir,
    out: PathBuf,
    run: std::process::Child,
    near: i32,
    join: std::process::Child,
    far_root: PathBuf,
    /// The law's controller log (the near bridge's words).
    log: PathBuf,
}

fn remote_controller_started(extra: &[&str]) -> RemoteController {
    let (tmp, cfg, key, ep) = s1_with_key();
    let out = tmp.path().join("run");
    let s = |p: &Path| p.to_str().unwrap().to_string();
    let (cfg, key_s, out_s) = (s(&cfg), s(&key), s(&out));
    let mut args = vec![
        "run",
        &cfg,
        "--mode",
        "realtime",
        "--controller-remote",
        &ep,
        "--link-key",
        &key_s,
    ];
    args.extend_from_slice(extra);
    args.extend_from_slice(&["--out", &out_s]);
    let run = common::spawn(&args);
    let near = near_bridge_of(run.id());
    let far_root = tmp.path().join("far-root");
    let join = join_as(&ep, "controller", &key, &far_root);
    let log = out.join("tdc.controller.log");
    let t0 = std::time::Instant::now();
    while !std::fs::read_to_string(&log).is_ok_and(|l| l.contains("direct path")) {
        assert!(
            t0.elapsed() < Duration::from_secs(60),
            "the loop never started"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
    RemoteController {
        tmp,
        out,
        run,
        near,
        join,
        far_root,
        log,
    }
}
