//! Ctrl-C on the plant's host, with either side remote and with the link down: both sides stop
//! and clean up.

use super::*;

#[test]
fn ctrl_c_on_the_plants_host_stops_both_sides_cleanly() {
    ctrl_c_stops_both_sides(
        "ctrl_c_on_the_plants_host_stops_both_sides_cleanly",
        Remote::Controller,
    );
}

#[test]
fn ctrl_c_with_the_plant_remote_stops_both_sides_cleanly() {
    ctrl_c_stops_both_sides(
        "ctrl_c_with_the_plant_remote_stops_both_sides_cleanly",
        Remote::Plant,
    );
}

/// Ctrl-C on the supervisor's host during a lockstep run with `remote` across the link: the run
/// is interrupted, the far process stops on the STOP that crossed, both roots are left empty.
fn ctrl_c_stops_both_sides(name: &str, remote: Remote) {
    let Some((h, _one)) = Hosts::new(name) else {
        return;
    };
    let out = h.tmp.path().join("remote");
    let join = h.join(remote.join_args());
    // `ip netns exec` and `env` exec in place: the child's pid is the supervisor's.
    let run = h.run_with(
        remote,
        "configs/s1-nominal.toml",
        &out,
        &["--mode", "lockstep", "--hold-s", "60"],
    );
    wait_for_the_loop(&out, 1000);
    // SAFETY: signalling our own child, not yet reaped.
    unsafe { libc::kill(run.id() as i32, libc::SIGINT) };
    let (r, j) = both(run, join, Duration::from_secs(30));
    assert_eq!(r.status.code(), Some(130), "run: {}", text(&r.stderr));
    let far = text(&j.stderr);
    assert_eq!(j.status.code(), Some(5), "join: {far}");
    assert!(far.contains("stopped by the supervisor (STOP)"), "{far}");
    let s = summary(&out);
    assert_eq!(outcome(&s, "tdc").0, RunStatus::Interrupted, "{s}");
    h.assert_roots_empty();
}

/// Regression: with the plant remote and the link down, Ctrl-C left the near bridge waiting for
/// a far end that could not come, until the supervisor killed it: no line said why, and its
/// iceoryx2 resources stayed in the supervisor host's root. It now gives up 700 ms after the
/// STOP, releases the controller and exits 5.
#[test]
fn regression_ctrl_c_with_the_link_down_and_the_plant_remote_cleans_up_here() {
    let Some((h, _one)) =
        Hosts::new("regression_ctrl_c_with_the_link_down_and_the_plant_remote_cleans_up_here")
    else {
        return;
    };
    let out = h.tmp.path().join("remote");
    let join = h.join(Remote::Plant.join_args());
    // Lockstep: the far plant waits for its controller (10 s silence) instead of braking at once.
    let run = h.run_with(
        Remote::Plant,
        "configs/s1-nominal.toml",
        &out,
        &["--mode", "lockstep", "--hold-s", "60"],
    );
    wait_for_the_loop(&out, 1000);
    ip(&["-n", &h.net.a, "link", "set", &h.net.veth_a, "down"]).unwrap();
    // SAFETY: signalling our own child, not yet reaped.
    unsafe { libc::kill(run.id() as i32, libc::SIGINT) };
    let r = common::finish_within(run, Duration::from_secs(30), "deltaloop run (side a)");
    // The far plant, cut off, waits out its silence timeout (lockstep) before it stops.
    let j = common::finish_within(join, Duration::from_secs(40), "deltaloop join (side b)");
    let err = text(&r.stderr);
    assert_eq!(r.status.code(), Some(130), "run: {err}");
    // The near bridge, the plant's stand-in, said why it gave up (its stderr is the plant's log).
    let log = std::fs::read_to_string(out.join("tdc.plant.log")).unwrap_or_default();
    assert!(
        log.contains("the far side did not report its end within 700 ms"),
        "{log}"
    );
    assert_ne!(j.status.code(), Some(0), "join: {}", text(&j.stderr));
    let s = summary(&out);
    assert_eq!(outcome(&s, "tdc").0, RunStatus::Interrupted, "{s}");
    h.assert_roots_empty();
}
