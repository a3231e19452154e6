//! Long realtime soak (ignored by default: ≈ 33 minutes). Run with
//! `cargo test --release --test soak -- --ignored --nocapture`.

mod common;

/// `configs/soak.toml` for 3 minutes, then for 30: the long run loses no tick, keeps every tick on
/// disk, and no process uses more than 1.2× the memory of the short run.
#[test]
#[ignore = "30-minute realtime soak; run it by name (docs/guide/live-and-soak.md, \"Long runs\")"]
fn soak_30_min_realtime_loses_nothing_and_memory_stays_flat() {
    let tmp = tempfile::tempdir().unwrap();
    let cfg = concat!(env!("CARGO_MANIFEST_DIR"), "/configs/soak.toml");
    let mut peaks = Vec::new();
    for hold in ["180", "1800"] {
        let out = tmp.path().join(format!("soak{hold}"));
        let s = common::run(cfg, "realtime", &out, &["--hold-s", hold]);
        let p = common::assert_complete_and_kept(&s, &out, "tdc-is-sta");
        let (m, t) = (&s["laws"]["tdc-is-sta"], &s["timing"]["tdc-is-sta"]);
        println!(
            "hold {hold} s: {} ticks, misses {}, round trip p99.9 {} µs, peak RSS MiB supervisor/plant/controller {p:?}",
            m["ticks"], t["deadline_misses"], t["round_trip"]["p999_us"]
        );
        peaks.push(p);
        let _ = std::fs::remove_dir_all(&out);
    }
    common::assert_memory_flat(peaks[0], peaks[1]);
}
