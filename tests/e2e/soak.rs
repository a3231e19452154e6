//! Long realtime soak (ignored by default: ≈ 33 minutes). Run with
//! `cargo test --release --test e2e soak:: -- --ignored --nocapture`.

use crate::common;

use common::{RunStatus, assert_every_tick_on_disk, disturbance, judge, on_a_noisy_host};

/// `configs/soak.toml` for 3 minutes, then for 30: each run ends with a typed status and every
/// tick it ran on disk, whatever the host does; if both completed (judged on runs the machine
/// left alone: see `common::on_a_noisy_host`), the long run lost no tick and no process uses
/// more than 1.2× the memory of the short run.
#[test]
#[ignore = "30-minute realtime soak; run it by name (docs/guide/live-and-soak.md, \"Long runs\")"]
fn soak_30_min_realtime_loses_nothing_and_memory_stays_flat() {
    let test = "soak_30_min_realtime_loses_nothing_and_memory_stays_flat";
    let law = "tdc-is-sta";
    let tmp = tempfile::tempdir().unwrap();
    let cfg = concat!(env!("CARGO_MANIFEST_DIR"), "/configs/soak.toml");
    let peaks = on_a_noisy_host(test, |n| {
        let mut peaks = Vec::new();
        for hold in ["180", "1800"] {
            let out = tmp.path().join(format!("soak{hold}-{n}"));
            let o = common::run_output(cfg, "realtime", &out, &["--hold-s", hold]);
            let s = common::summary(&out);
            let status = assert_every_tick_on_disk(&s, &out, law);
            let err = String::from_utf8_lossy(&o.stderr);
            assert_eq!(o.status.success(), status.is_physical(), "{err}");
            let completed = (status == RunStatus::Ok)
                .then_some(())
                .ok_or_else(|| format!("hold {hold} s: {status:?}: {err}"));
            let judged = judge(disturbance(&s, law), completed);
            if judged.is_err() {
                let _ = std::fs::remove_dir_all(&out);
            }
            judged?;
            let p = common::assert_complete_and_kept(&s, &out, law);
            let (m, t) = (&s["laws"][law], &s["timing"][law]);
            println!(
                "hold {hold} s: {} ticks, misses {}, round trip p99.9 {} µs, {} pause(s) ({} ms), peak RSS MiB supervisor/plant/controller {p:?}",
                m["ticks"],
                t["deadline_misses"],
                t["round_trip"]["p999_us"],
                t["pauses"],
                t["paused_ms"]
            );
            peaks.push(p);
            let _ = std::fs::remove_dir_all(&out);
        }
        Ok(peaks)
    });
    if let Some(peaks) = peaks {
        common::assert_memory_flat(peaks[0], peaks[1]);
    }
}
