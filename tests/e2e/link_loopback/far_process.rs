//! The far process's own end: a step error stops the loop at once, a user's process is labelled
//! as such on the supervisor's host.

use super::*;

/// Regression: a far controller whose step reported an error (it said CONTROLLER_ERROR) stopped
/// a lockstep loop only after the plant's silence timeout (2 s): the near bridge passed the
/// message on but did not wake the plant, which reads it when it wakes. The plant stops at the
/// failing tick at once, naming the error, as on one host.
#[test]
fn regression_a_far_controller_step_error_stops_the_lockstep_loop_at_once() {
    let Some(exe) = common::c_peer("c_controller_faults") else {
        return;
    };
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let (tmp, cfg, key, ep) = s1_with_key();
    let out = tmp.path().join("remote");
    let run = common::spawn(&remote_lockstep(&cfg, &ep, &key, &out));
    let far_root = tmp.path().join("far-root");
    let join = join_with_cmd(&ep, &key, &far_root, &format!("{} fail@200", exe.display()));
    let (o, _) = finish_pair(run, join, &far_root);
    assert_eq!(o.status.code(), Some(1), "{}", text(&o.stderr));
    common::assert_step_error_stopped_the_loop_at_once(
        &out,
        "the controller reported an error at tick 200",
    );
}

/// Regression: with the plant remote, a controller whose step reported an error (it said
/// CONTROLLER_ERROR) stopped the far lockstep plant only after its silence timeout (2 s): the
/// far bridge republished the message there but did not wake the plant, which reads it when it
/// wakes. The far plant stops at the failing tick at once, naming the error, as on one host.
#[test]
fn regression_a_controller_step_error_stops_a_far_lockstep_plant_at_once() {
    let Some(exe) = common::c_peer("c_controller_faults") else {
        return;
    };
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let (tmp, cfg, key, ep) = s1_with_key();
    let out = tmp.path().join("remote");
    let s = |p: &Path| p.to_str().unwrap().to_string();
    let controller = format!("--controller-cmd={} fail@200", exe.display());
    let args = [
        "run",
        &s(&cfg),
        "--mode",
        "lockstep",
        "--plant-remote",
        &ep,
        "--link-key",
        &s(&key),
        &controller,
        "--out",
        &s(&out),
    ];
    let run = common::spawn(&args);
    let far_root = tmp.path().join("far-root");
    let join = join_as(&ep, "plant", &key, &far_root);
    let (o, _) = finish_pair(run, join, &far_root);
    assert_eq!(o.status.code(), Some(1), "{}", text(&o.stderr));
    common::assert_step_error_stopped_the_loop_at_once(
        &out,
        "the controller reported an error at tick 200",
    );
}

/// Regression: a foreign controller on the far host was not labelled on the supervisor's host:
/// the label falls back to the run's `controller.command`, which with `--controller-remote` is
/// empty (the command is `join --controller-cmd`'s). The far bridge names a controller that
/// does not name itself in its READY after its command, as a local one is named: the terminal
/// table, summary.json and report.md show it.
#[test]
fn regression_a_far_controller_of_the_users_is_labelled_on_the_supervisors_host() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let (tmp, cfg, key, ep) = s1_with_key();
    // The built-in controller under a name of this test's (it says nothing in its READY).
    let named = tmp.path().join("rig-law-7");
    std::os::unix::fs::symlink(env!("CARGO_BIN_EXE_deltaloop-controller"), &named).unwrap();
    let out = tmp.path().join("remote");
    let run = common::spawn(&remote_lockstep(&cfg, &ep, &key, &out));
    let far_root = tmp.path().join("far-root");
    let join = join_with_cmd(&ep, &key, &far_root, named.to_str().unwrap());
    let (o, j) = finish_pair(run, join, &far_root);
    assert!(o.status.success(), "{}", text(&o.stderr));
    assert!(j.status.success(), "join: {}", text(&j.stderr));
    assert_eq!(summary(&out)["controller_label"], "rig-law-7");
    let stdout = text(&o.stdout);
    assert!(stdout.contains("tdc (rig-law-7)"), "{stdout}");
    let report = std::fs::read_to_string(out.join("report.md")).unwrap();
    assert!(report.contains("Controller: `rig-law-7`"), "{report}");
}
