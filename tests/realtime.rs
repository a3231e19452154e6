//! A realtime run of the real process pair: it tracks S1 as well as the inproc run allows, given
//! its measured latency and the deadlines it missed, writes its timing histograms, and replays
//! byte for byte. Its own test binary, so no other
//! test's processes share the CPUs with it (cargo runs test binaries one at a time).

mod common;

use common::{assert_clean, run};

#[test]
fn realtime_run_tracks_s1_close_to_inproc_and_writes_histograms() {
    let tmp = tempfile::tempdir().unwrap();
    let (a, b) = (tmp.path().join("inproc"), tmp.path().join("rt"));
    let laws = ["--law", "tde-is", "--law", "pid"];
    let si = run("configs/s1-nominal.toml", "inproc", &a, &laws);
    let sr = run("configs/s1-nominal.toml", "realtime", &b, &laws);
    for law in ["tde-is", "pid"] {
        let m = &sr["laws"][law];
        assert_eq!(m["completed"], true, "{law}: {m}");
        let t = &sr["timing"][law];
        let misses = t["deadline_misses"].as_f64().unwrap();
        assert!(t["miss_ratio"].as_f64().unwrap() < 0.05, "{law}: {t}");
        for j in 0..3 {
            let (r, i) = (
                m["rms_rad"][j].as_f64().unwrap(),
                si["laws"][law]["rms_rad"][j].as_f64().unwrap(),
            );
            // Each missed deadline holds the last torque for a tick. With the matched laws tracking
            // to ~4e-8 rad, that shows: measured on 2 vCPUs, 9 / 36 / 72 misses raised tde-is's
            // joint-0 RMS by 0.19 / 0.44 / 0.69 µrad. The allowance, 1 µrad + 0.1 µrad per miss,
            // tops out at 14 µrad at the 5 % miss ceiling below: still 30x under the smallest wiring
            // error, one extra tick of delay, which costs tde-is 4e-4 rad (docs/delay-sweep).
            let allowed = 3.0 * i + 1e-6 + 1e-7 * misses;
            assert!(
                r < allowed,
                "{law} joint {j}: realtime {r:e} vs inproc {i:e}, allowed {allowed:e} \
                 with {misses} misses; timing: {t}"
            );
        }
        assert_eq!(t["ticks"], 2668);
        assert!(t["round_trip"]["p50_us"].as_f64().unwrap() > 0.0);
        for h in [
            "round_trip",
            "wake_lateness",
            "period_jitter",
            "state_to_controller",
            "controller_compute",
        ] {
            let text = std::fs::read_to_string(b.join(format!("{law}.{h}.hgrm"))).unwrap();
            assert!(
                text.lines()
                    .filter(|l| l.trim_start().starts_with(|c: char| c.is_ascii_digit()))
                    .count()
                    > 10,
                "{law}.{h}.hgrm is thin"
            );
        }
    }
    let report = std::fs::read_to_string(b.join("report.md")).unwrap();
    assert!(report.contains("## Loop timing (realtime)") && report.contains("deadline misses"));
    assert!(report.contains("measured latency cost: RMS ×"), "{report}");
    // Each reply acted at its measured arrival, recorded per tick: the run replays in-process
    // byte for byte from its folder alone.
    let trace = std::fs::read_to_string(b.join("trace.csv")).unwrap();
    let arrivals: Vec<u64> = trace
        .lines()
        .skip(1)
        .filter_map(|l| l.rsplit(',').next()?.parse().ok())
        .collect();
    // Measured from the tick's deadline: a real latency (tens of µs at the median), longer when
    // the plant woke late, never absurd.
    let mut sorted = arrivals.clone();
    sorted.sort_unstable();
    assert!(arrivals.len() > 5000, "{} arrivals", arrivals.len());
    assert!(
        sorted[sorted.len() / 2] > 1_000,
        "median arrival {} ns",
        sorted[sorted.len() / 2]
    );
    assert!(*sorted.last().unwrap() < 1_000_000_000);
    let o = common::deltaloop(&["replay", b.to_str().unwrap()]);
    let (out, err) = (
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr),
    );
    assert!(
        o.status.success() && out.contains("byte for byte"),
        "{out}{err}"
    );
    assert_clean(&b, &sr);
}
