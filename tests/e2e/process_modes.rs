//! End-to-end with real processes over iceoryx2 in lockstep: lockstep ≡ inproc bit for bit, two
//! runs at once, and nothing left behind. The realtime run has its own test binary (realtime.rs).

use crate::common;

use common::{assert_clean, run};
use serde_json::Value;
use std::path::PathBuf;
use std::process::Command;

#[test]
fn lockstep_is_bit_identical_to_inproc_and_leaves_nothing_behind() {
    let tmp = tempfile::tempdir().unwrap();
    let (a, b) = (tmp.path().join("inproc"), tmp.path().join("lockstep"));
    // Every law, the implicit super-twisting one (not in the configs' default list) included.
    let mut args = vec!["--force"];
    for law in ["tdc", "tde-is", "tdc-is-sta", "tdc-is-ista", "pid"] {
        args.extend(["--law", law]);
    }
    for cfg in ["configs/s2-fast.toml", "configs/paper/s2-fast.toml"] {
        // The second config reuses both folders: --force empties them first.
        let si = run(cfg, "inproc", &a, &args);
        let sl = run(cfg, "lockstep", &b, &args);
        let ti = std::fs::read(a.join("trace.csv")).unwrap();
        let tl = std::fs::read(b.join("trace.csv")).unwrap();
        assert!(ti.len() > 100_000);
        assert!(ti == tl, "{cfg}: lockstep trace.csv differs from inproc");
        assert_eq!(si["laws"], sl["laws"], "{cfg}: metrics differ");
        // Lockstep waits for every torque: no misses, nothing lost.
        for (law, t) in sl["timing"].as_object().unwrap() {
            assert_eq!(t["deadline_misses"], 0, "{law}");
            assert_eq!(t["supervisor_lost_samples"]["state"], 0, "{law}");
            assert!(t["round_trip"]["count"].as_u64().unwrap() >= 667, "{law}");
        }
        assert_clean(&b, &sl);
    }
}

#[test]
fn two_runs_at_once_do_not_interfere() {
    let tmp = tempfile::tempdir().unwrap();
    let spawn = |cfg: &str, law: &str, out: PathBuf| {
        Command::new(env!("CARGO_BIN_EXE_deltaloop"))
            .args([
                "run",
                cfg,
                "--mode",
                "lockstep",
                "--law",
                law,
                "--out",
                out.to_str().unwrap(),
            ])
            .current_dir(env!("CARGO_MANIFEST_DIR"))
            .output()
            .unwrap()
    };
    let (o1, o2) = (tmp.path().join("one"), tmp.path().join("two"));
    let h1 = {
        let o = o1.clone();
        std::thread::spawn(move || spawn("configs/s2-fast.toml", "tdc-is-sta", o))
    };
    let h2 = {
        let o = o2.clone();
        std::thread::spawn(move || spawn("configs/s2-fast.toml", "tde-is", o))
    };
    for (h, dir, law) in [(h1, &o1, "tdc-is-sta"), (h2, &o2, "tde-is")] {
        let out = h.join().unwrap();
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        // Each equals its own inproc run: no sample crossed over.
        let reference = tmp.path().join(format!("ref-{law}"));
        let si = run(
            "configs/s2-fast.toml",
            "inproc",
            &reference,
            &["--law", law],
        );
        let s: Value =
            serde_json::from_str(&std::fs::read_to_string(dir.join("summary.json")).unwrap())
                .unwrap();
        assert_eq!(s["laws"][law], si["laws"][law], "{law}");
        assert_eq!(
            std::fs::read(dir.join("trace.csv")).unwrap(),
            std::fs::read(reference.join("trace.csv")).unwrap()
        );
    }
}

/// Regression: the plant process once ignored the transport delay, the sensor model and the
/// payload step (it built its plant without them); lockstep must equal inproc with all three on.
#[test]
fn lockstep_equals_inproc_with_delay_noise_and_payload() {
    let tmp = tempfile::tempdir().unwrap();
    let cfg = tmp.path().join("all.toml");
    std::fs::write(
        &cfg,
        "[scenario]\npath = \"s2\"\n[plant]\nfriction = true\ntransport_delay_samples = 2\npayload_step_kg = 0.5\n\
         [controller]\nlaws = [\"tdc\", \"tdc-is-sta\"]\ntde_delay_samples = 3\n\
         [sensor]\nencoder_counts_per_rev = 1048576\nq_noise_std_rad = 1e-6\nqd_noise_std_rad_s = 1e-3\nseed = 9\n",
    )
    .unwrap();
    let (a, b) = (tmp.path().join("inproc"), tmp.path().join("lockstep"));
    let si = run(cfg.to_str().unwrap(), "inproc", &a, &[]);
    let sl = run(cfg.to_str().unwrap(), "lockstep", &b, &[]);
    assert!(
        std::fs::read(a.join("trace.csv")).unwrap() == std::fs::read(b.join("trace.csv")).unwrap(),
        "traces differ"
    );
    assert_eq!(si["laws"], sl["laws"]);
    // And the options really acted: the run differs from one without them.
    let plain = tmp.path().join("plain");
    let sp = run("configs/s2-fast.toml", "inproc", &plain, &["--law", "tdc"]);
    assert_ne!(sp["laws"]["tdc"]["rms_rad"], si["laws"]["tdc"]["rms_rad"]);
}
