//! The plant on the other host (`--plant-remote`): byte-identical lockstep, realtime with its
//! round trip, the link pulled mid-run.

use super::*;

#[test]
fn lockstep_with_the_plant_remote_is_byte_identical_to_inproc() {
    let Some((h, _one)) = Hosts::new("lockstep_with_the_plant_remote_is_byte_identical_to_inproc")
    else {
        return;
    };
    // A lossy, slow, jittery link too: the plant's side sends a state again until its reply
    // comes; the telemetry and the plant's control cross over TCP.
    assert_lockstep_identical_with(&h, Remote::Plant, LOSSY, &[]);
}

#[test]
fn realtime_with_the_plant_remote_completes_measures_the_round_trip_and_replays() {
    realtime_across_the_link_with(
        "realtime_with_the_plant_remote_completes_measures_the_round_trip_and_replays",
        Remote::Plant,
        &[],
        false,
    );
}

#[test]
fn pulling_the_link_with_the_plant_remote_ends_in_its_safe_stop_there() {
    let test = "pulling_the_link_with_the_plant_remote_ends_in_its_safe_stop_there";
    let Some((h, _one)) = Hosts::new(test) else {
        return;
    };
    let Some((out, r, j)) = cut_the_link_mid_run(&h, Remote::Plant, test) else {
        return;
    };
    let err = text(&r.stderr);
    assert_eq!(r.status.code(), Some(1), "run: {err}");
    assert!(
        err.contains("the link to the plant's host went silent"),
        "{err}"
    );
    // The far plant's stamps are on its own clock: not compared with this host's.
    assert!(!err.contains("saw the plant exit"), "{err}");
    // The plant, far away, ran out of replies and applied its own rules there: it held the last
    // torque through the silence window, then braked to its safe stop; or the held torque drifted
    // the robot into its singularity margins first (physics: where the cut caught the motion
    // decides), and it stopped with no safe stop possible. Either way it exits 4 and says so.
    let far = text(&j.stderr);
    assert_eq!(j.status.code(), Some(4), "join: {far}");
    let braked = far.contains("no torque within the budget") && far.contains("safe stop");
    let flung = far.contains("no safe stop possible");
    assert!(braked || flung, "{far}");
    if braked {
        // Every tick whose telemetry crossed before the cut is on disk (the fault is at the tick
        // after the last one), and after it only the few ticks whose state and the controller's
        // reply were seen here but whose telemetry did not cross (a tick's telemetry leaves the
        // plant's host with the next state, over TCP): at most 32 (10 ms).
        assert_fault_after_the_cut(&out, FaultKind::PlantFailed, 32);
    } else {
        // The far plant's DIVERGED names a tick this side never saw (after the cut): the run is
        // a fault with every tick that crossed on disk, none lost.
        let s = summary(&out);
        assert_eq!(outcome(&s, "tdc").0, RunStatus::Fault, "{s}");
        assert_every_tick_on_disk(&s, &out, "tdc");
    }
    h.assert_roots_empty();
}
