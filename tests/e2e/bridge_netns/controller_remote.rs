//! The controller on the other host (`--controller-remote`): byte-identical lockstep, realtime
//! with its round trip, a held-up far bridge, a lossy link, the link pulled mid-run.

use super::*;

#[test]
fn lockstep_across_the_link_is_byte_identical_to_inproc() {
    let Some((h, _one)) = Hosts::new("lockstep_across_the_link_is_byte_identical_to_inproc") else {
        return;
    };
    // A lossy, slow, jittery link too: lockstep sends a state again until its reply comes, on
    // the direct path (the plant's and the controller's own sockets), then on the relay.
    let log = assert_lockstep_identical(&h, LOSSY, &[]);
    assert!(far_went_direct(&log), "{log}");
    let relay: Vec<&str> = LOSSY
        .iter()
        .copied()
        .chain(["--link-path", "relay"])
        .collect();
    let log = assert_lockstep_identical(&h, &relay, &[]);
    assert!(
        !far_went_direct(&log) && log.contains("the relay path"),
        "{log}"
    );
}

/// The done-when: a realtime run across the link completes, its report shows the link's
/// round trip, and the same run replays byte for byte.
#[test]
fn realtime_across_the_link_completes_measures_the_round_trip_and_replays() {
    realtime_across_the_link(
        "realtime_across_the_link_completes_measures_the_round_trip_and_replays",
        &[],
        false,
    );
}

/// Regression: a far bridge held up by its host for a few ticks found more replies queued than
/// its torque queue held ([`LOOP_BUFFER`](deltaloop_transport::ipc::LOOP_BUFFER), 4) and lost the
/// oldest; the plant's host recorded as unanswered states the far controller had answered, and
/// about half the realtime runs across the link did not replay. The far bridge is stopped for
/// 8 ms every 60 ms here (SIGSTOP/SIGCONT), so each stop queues dozens of states behind it. The
/// relay path's: on the direct path the far bridge is not on the loop's path, and holding it up
/// costs no tick (`link_loopback::regression_a_stalled_bridge_run_replays_or_says_what_it_lost`).
#[test]
fn regression_a_far_bridge_held_up_loses_no_reply_and_the_run_replays() {
    realtime_across_the_link(
        "regression_a_far_bridge_held_up_loses_no_reply_and_the_run_replays",
        &["--link-path", "relay"],
        true,
    );
}

/// A reply datagram lost on the wire is recovered from the next one (each carries the two
/// replies before it), so a run over a link losing 1 % of its datagrams each way still replays
/// byte for byte (a lost state is a state the controller never saw: recorded `missed`).
#[test]
fn realtime_across_a_lossy_link_replays_byte_for_byte() {
    realtime_across_the_link(
        "realtime_across_a_lossy_link_replays_byte_for_byte",
        &["--link-loss", "0.01", "--link-seed", "5"],
        false,
    );
}

#[test]
fn pulling_the_link_mid_run_ends_in_a_safe_stop_with_every_tick_kept() {
    let test = "pulling_the_link_mid_run_ends_in_a_safe_stop_with_every_tick_kept";
    let Some((h, _one)) = Hosts::new(test) else {
        return;
    };
    let Some((out, r, j)) = cut_the_link_mid_run(&h, Remote::Controller, test) else {
        return;
    };
    let err = text(&r.stderr);
    assert_eq!(r.status.code(), Some(1), "run: {err}");
    assert!(err.contains("safe stop"), "{err}");
    assert_ne!(j.status.code(), Some(0), "join: {}", text(&j.stderr));
    // Every tick up to the fault is on disk, nothing after it.
    assert_fault_after_the_cut(&out, FaultKind::ControllerSilent, 0);
    h.assert_roots_empty();
}
