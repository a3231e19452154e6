//! The supervisor itself stopped (SIGSTOP) while the loop runs or the pair exits: ticks may
//! be lost, never the run.

use super::*;

/// Regression: a supervisor stopped for 3 s (SIGSTOP) lost part of the stream when its queues
/// overflowed, and turned good data into a "divergence" at the first hole, dropping every tick
/// after it. Now the lost ticks are counted and named, the run ends as "lost data", and every
/// tick the supervisor saw, before and after the hole, is kept.
#[test]
fn regression_a_stopped_supervisor_loses_ticks_not_the_run() {
    let tmp = tempfile::tempdir().unwrap();
    let cfg = config(tmp.path(), 5.0, "");
    // The queues hold 8192 ticks (2.5 s). A host that holds the plant back (it pauses simulated
    // time over its own stalls) can keep the 3.5 s stop's ticks below that, and then nothing is
    // lost: that is the machine, not the supervisor, and the run is tried again.
    common::on_a_noisy_host(
        "regression_a_stopped_supervisor_loses_ticks_not_the_run",
        |n| stopped_supervisor_run(&cfg, &tmp.path().join(format!("run-{n}"))),
    );
}

/// One attempt of the test above: Err when the run lost nothing on a host that stalled its plant.
fn stopped_supervisor_run(cfg: &str, out: &Path) -> Result<(), String> {
    let child = spawn(&["run", cfg, "--out", out.to_str().unwrap()]);
    signal_child(out, "deltaloop-plant", 0, 800);
    let sup = child.id() as i32;
    // SAFETY: stopping and resuming our own child.
    unsafe { libc::kill(sup, libc::SIGSTOP) };
    std::thread::sleep(Duration::from_millis(3500));
    unsafe { libc::kill(sup, libc::SIGCONT) };
    let (code, err) = finish(child);
    if code == Some(0) {
        let s = summary(out);
        return match common::plant_stalled(&s, "tdc") {
            Some(why) => Err(format!("nothing lost: the plant ran too few ticks ({why})")),
            None => panic!("nothing lost in an undisturbed run: {}", s["timing"]["tdc"]),
        };
    }
    assert_eq!(code, Some(1), "{err}");
    assert_eq!(err.trim().lines().count(), 1, "{err}");
    assert!(
        err.contains("lost data") && err.contains("fell behind"),
        "{err}"
    );
    let s = summary(out);
    let m = &s["laws"]["tdc"];
    assert_eq!(outcome(&s, "tdc"), (RunStatus::LostData, None), "{m}");
    // At most the ticks of the 3.5 s stop; how many more than the queue held depends on how
    // many ticks the loop ran meanwhile, which a loaded host lowers (the plant pauses its
    // simulated time over its own stalls): a host's bad hour made it 85, so only "some".
    let lost = m["lost_ticks"].as_u64().unwrap();
    assert!((1..12_000).contains(&lost), "lost {lost}: {m}");
    let trace = std::fs::read_to_string(out.join("trace.csv")).unwrap();
    let ks: Vec<u64> = trace
        .lines()
        .skip(1)
        .map(|l| l.split(',').nth(1).unwrap().parse().unwrap())
        .collect();
    let n = s["ticks"].as_u64().unwrap();
    assert_eq!(*ks.last().unwrap(), n, "the trace goes on to the last tick");
    assert_eq!(
        ks.len() as u64 + lost,
        n + 1,
        "every tick is either kept or counted lost"
    );
    Ok(())
}

/// A supervisor stopped (SIGSTOP) while the plant and the controller finish and exit keeps every
/// tick: what they published stays in its queues after they are gone (iceoryx2 keeps a gone
/// publisher's samples for a subscriber that has not taken them), so no drain step is needed
/// before a loop process exits. The stop is shorter than the queues (8192 ticks), so nothing
/// can overflow: any loss would be the exit's.
#[test]
fn a_supervisor_stopped_while_the_pair_exits_loses_no_tick() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("run");
    // 0.8 s of motion and 1 s of hold: 6000 ticks, stopped from 1.4 s to 3.4 s.
    let cfg = config(tmp.path(), 1.0, "");
    let child = spawn(&["run", &cfg, "--out", out.to_str().unwrap()]);
    signal_child(&out, "deltaloop-plant", 0, 1400);
    let sup = child.id() as i32;
    // SAFETY: stopping and resuming our own child.
    unsafe { libc::kill(sup, libc::SIGSTOP) };
    let t0 = Instant::now();
    // Until both loop processes have exited (at most 5 s), then 200 ms more.
    while !pids_of(&out, "deltaloop-plant").is_empty()
        || !pids_of(&out, "deltaloop-controller").is_empty()
    {
        assert!(
            t0.elapsed() < Duration::from_secs(5),
            "the pair never exited"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
    std::thread::sleep(Duration::from_millis(200));
    unsafe { libc::kill(sup, libc::SIGCONT) };
    let (code, err) = finish(child);
    let s = summary(&out);
    // Whatever the host did to the loop (a fault, on a bad hour): nothing the supervisor
    // missed, since it saw every message once it resumed.
    assert_eq!(s["laws"]["tdc"]["lost_ticks"], 0, "{err}: {s}");
    assert_eq!(s["laws"]["tdc"]["telemetry_missing"], 0, "{err}: {s}");
    for stream in ["state", "torque", "telemetry"] {
        assert_eq!(
            s["timing"]["tdc"]["supervisor_lost_samples"][stream], 0,
            "{s}"
        );
    }
    let status = common::assert_every_tick_on_disk(&s, &out, "tdc");
    if status != RunStatus::Ok || code != Some(0) {
        let why = format!("{status:?}, exit {code:?}: {err}");
        let judged = common::judge(common::disturbance(&s, "tdc"), Err(why));
        eprintln!("the loop itself was disturbed: {judged:?}");
    }
}
