//! End-to-end: `deltaloop sweep` (divergence recorded, files complete), CLI delay overrides, and a
//! realtime compute delay that produces real misses.

use crate::common;

use common::{FaultKind, RunStatus, deltaloop, json, outcome};
use std::path::Path;

#[test]
fn sweep_records_divergence_and_writes_table_and_plots() {
    let tmp = tempfile::tempdir().unwrap();
    let base = Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/s2-fast.toml");
    let sweep = tmp.path().join("small.toml");
    std::fs::write(
        &sweep,
        format!(
            "name = \"small\"\nbase = {:?}\nscenarios = [\"s2\"]\npresets = [\"paper\"]\nlaws = [\"tdc\", \"tde-is\"]\ntde_delay_samples = [1, 2, 3]\ntransport_delay_samples = [0, 8]\n",
            base.display().to_string()
        ),
    )
    .unwrap();
    let out = tmp.path().join("out");
    let o = deltaloop(&[
        "sweep",
        sweep.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    // The folder belongs to that sweep: a second sweep into it is refused unless --force, which
    // empties it first (regression: sweeps, like runs, once reused a folder silently).
    let again = |extra: &[&str]| {
        let mut args = vec![
            "sweep",
            sweep.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ];
        args.extend_from_slice(extra);
        deltaloop(&args)
    };
    let o = again(&[]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(
        err.contains("is not empty") && err.contains("--force"),
        "{err}"
    );
    let o = again(&["--force"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let rows = json(&out.join("sweep.json"));
    let rows = rows.as_array().unwrap();
    assert_eq!(rows.len(), 2 * 3 * 2);
    // S2, paper preset, tdc, ℓ = 1, d = 8 diverges (tracking error above 0.5 rad): recorded, not fatal.
    let div = rows
        .iter()
        .find(|r| {
            r["law"] == "tdc" && r["tde_delay_samples"] == 1 && r["transport_delay_samples"] == 8
        })
        .unwrap();
    let status: RunStatus = serde_json::from_value(div["status"].clone()).unwrap();
    assert_eq!(status, RunStatus::Diverged, "{div}");
    let tick = div["diverged_at_tick"].as_u64().unwrap();
    assert!(tick > 0 && tick < 667);
    // Rows without delay are fine, and the TDE error grows with ℓ at d = 0.
    let tde = |law: &str, l: u64| {
        rows.iter()
            .find(|r| {
                r["law"] == law && r["tde_delay_samples"] == l && r["transport_delay_samples"] == 0
            })
            .unwrap()["tde_err_rms"]
            .as_f64()
            .unwrap()
    };
    assert!(tde("tdc", 1) < tde("tdc", 2) && tde("tdc", 2) < tde("tdc", 3));
    // The same numbers as `deltaloop run` of that point (preset `paper`, ℓ = 3 given on the CLI).
    let run_dir = tmp.path().join("run");
    let r = deltaloop(&[
        "run",
        "configs/paper/s2-fast.toml",
        "--mode",
        "inproc",
        "--law",
        "tdc",
        "--tde-delay",
        "3",
        "--out",
        run_dir.to_str().unwrap(),
    ]);
    assert!(r.status.success());
    let cfg = std::fs::read_to_string(run_dir.join("config.toml")).unwrap();
    assert!(
        cfg.contains("tde_delay_samples = 3"),
        "the override reaches the resolved config: {cfg}"
    );
    let s = json(&run_dir.join("summary.json"));
    let from_run = s["laws"]["tdc"]["tde_err_rms"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .fold(0.0, f64::max);
    assert_eq!(from_run, tde("tdc", 3));
    // Files: csv with a header and every row, a report with the divergence, non-trivial plots.
    let csv = std::fs::read_to_string(out.join("sweep.csv")).unwrap();
    assert_eq!(csv.lines().count(), 1 + rows.len());
    let report = std::fs::read_to_string(out.join("report.md")).unwrap();
    assert!(report.contains(&format!("div@{tick}")), "{report}");
    for stem in [
        "rms_vs_tde_delay",
        "tde_err_vs_tde_delay",
        "delta_n_vs_tde_delay",
        "rms_vs_transport_delay",
    ] {
        let png = std::fs::read(out.join(format!("{stem}.png"))).unwrap();
        assert!(
            png.starts_with(b"\x89PNG") && png.len() > 10_000,
            "{stem}.png: {} bytes",
            png.len()
        );
        // PNG width and height (IHDR) are the figure's, not a stub's.
        let (w, h) = (
            u32::from_be_bytes(png[16..20].try_into().unwrap()),
            u32::from_be_bytes(png[20..24].try_into().unwrap()),
        );
        assert!(w >= 600 && h >= 400, "{stem}.png is {w}x{h}");
        let svg = std::fs::read_to_string(out.join(format!("{stem}.svg"))).unwrap();
        assert!(
            svg.matches("<polyline").count() >= 2
                && svg.contains("tde-is")
                && svg.contains("<text"),
            "{stem}.svg lacks series or labels"
        );
    }
}

#[test]
fn bad_sweep_and_override_values_are_named() {
    let tmp = tempfile::tempdir().unwrap();
    let sweep = tmp.path().join("bad.toml");
    let base = Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/s1-nominal.toml");
    std::fs::write(&sweep, format!("name = \"b\"\nbase = {:?}\nscenarios = [\"s1\"]\npresets = [\"matched\"]\nlaws = [\"tdc\"]\ntde_delay_samples = [0]\ntransport_delay_samples = [0]\n", base.display().to_string())).unwrap();
    let o = deltaloop(&[
        "sweep",
        sweep.to_str().unwrap(),
        "--out",
        tmp.path().join("o").to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1));
    assert!(
        err.contains("controller.tde_delay_samples") && err.contains("= 0"),
        "{err}"
    );
    let o = deltaloop(&[
        "run",
        "configs/s1-nominal.toml",
        "--mode",
        "inproc",
        "--transport-delay",
        "20000",
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("plant.transport_delay_samples") && err.contains("20000"),
        "{err}"
    );
}

#[test]
fn realtime_compute_delay_longer_than_the_period_misses_and_is_reported() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("rt");
    let o = deltaloop(&[
        "run",
        "configs/s2-fast.toml",
        "--mode",
        "realtime",
        "--law",
        "tdc",
        "--compute-delay-us",
        "1000",
        "--out",
        out.to_str().unwrap(),
    ]);
    // Every reply is late: after 100 consecutive misses the plant declares the controller unusable,
    // brakes to a safe stop, and the run ends with that fault (exit 1), data kept.
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    let s = json(&out.join("summary.json"));
    assert_eq!(
        outcome(&s, "tdc"),
        (RunStatus::Fault, Some(FaultKind::ControllerSilent))
    );
    // The plant says the replies came late (dropped), not that none came.
    assert!(err.contains("late replies dropped"), "{err}");
    let t = &s["timing"]["tdc"];
    let (misses, ticks) = (
        t["deadline_misses"].as_u64().unwrap(),
        t["ticks"].as_u64().unwrap(),
    );
    // Every reply comes 1 ms after its state, beyond the 150 µs budget: nearly every tick misses.
    assert!(misses * 10 >= ticks * 9, "{misses} of {ticks}");
    assert!(t["controller_compute"]["p50_us"].as_f64().unwrap() >= 1000.0);
    // The fault is recorded on the law, with the tick the hold window ended.
    assert_eq!(s["laws"]["tdc"]["status_tick"].as_u64(), Some(99));
    assert_eq!(s["laws"]["tdc"]["fault_at_tick"].as_u64(), Some(99));
    let report = std::fs::read_to_string(out.join("report.md")).unwrap();
    assert!(
        report.contains("controller compute delay 1000 µs"),
        "{report}"
    );
}
