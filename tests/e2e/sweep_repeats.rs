//! End-to-end: a sweep with `repeats` runs each point over several sensor-noise seeds and writes
//! the mean, standard deviation and 95 % CI of each headline metric, the round-off spread of its
//! twin, and figures with error bars.

use crate::common;

use common::{deltaloop, summary};

const BASE: &str = "name = \"noisy\"\n[scenario]\npath = \"s2\"\n[plant]\nfriction = true\n[controller]\nlaws = [\"tdc\"]\n[sensor]\nencoder_counts_per_rev = 4194304\nq_noise_std_rad = 2e-7\nqd_noise_std_rad_s = 1e-3\nseed = 7\n";

const SWEEP: &str = "name = \"rep\"\nbase = \"base.toml\"\nscenarios = [\"s2\"]\npresets = [\"matched\"]\nlaws = [\"tde-is\"]\ntde_delay_samples = [1, 2]\ntransport_delay_samples = [0]\nrepeats = 3\n";

#[test]
fn sweep_repeats_write_mean_std_ci_and_error_bars() {
    let tmp = tempfile::tempdir().unwrap();
    std::fs::write(tmp.path().join("base.toml"), BASE).unwrap();
    let sweep = tmp.path().join("sweep.toml");
    std::fs::write(&sweep, SWEEP).unwrap();
    let out = tmp.path().join("out");
    let o = deltaloop(&[
        "sweep",
        sweep.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));

    let mut rd = csv::Reader::from_path(out.join("sweep.csv")).unwrap();
    let h = rd.headers().unwrap().clone();
    let col = |n: &str| {
        h.iter()
            .position(|x| x == n)
            .unwrap_or_else(|| panic!("no {n}"))
    };
    let rows: Vec<csv::StringRecord> = rd.records().map(Result::unwrap).collect();
    assert_eq!(rows.len(), 2);
    let f = |r: &csv::StringRecord, n: &str| r[col(n)].parse::<f64>().unwrap();
    let at_ell1 = rows
        .iter()
        .find(|r| &r[col("tde_delay_samples")] == "1")
        .unwrap();
    assert_eq!(
        (
            &at_ell1[col("repeats")],
            &at_ell1[col("repeats_ok")],
            &at_ell1[col("seed")]
        ),
        ("3", "3", "7")
    );

    // The same point by hand: `deltaloop run` at seeds 7, 8, 9; mean, sample std (n − 1) and
    // mean ± t₀.₉₇₅,₂ · s/√3 with t₀.₉₇₅,₂ = 4.302652729911275.
    let cfg = tmp.path().join("point.toml");
    std::fs::write(&cfg, BASE).unwrap();
    let mut xs = Vec::new();
    for seed in ["7", "8", "9"] {
        let dir = tmp.path().join(format!("seed{seed}"));
        let o = deltaloop(&[
            "run",
            cfg.to_str().unwrap(),
            "--mode",
            "inproc",
            "--law",
            "tde-is",
            "--seed",
            seed,
            "--out",
            dir.to_str().unwrap(),
        ]);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        xs.push(common::max_joint_rms(&summary(&dir), "tde-is"));
    }
    assert!(xs[0] != xs[1], "the seeds must differ: {xs:?}");
    let mean = xs.iter().sum::<f64>() / 3.0;
    let sd = (xs.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / 2.0).sqrt();
    let half = 4.302652729911275 * sd / 3f64.sqrt();
    let close = |a: f64, b: f64, what: &str| {
        assert!(
            (a / b - 1.0).abs() < 1e-9,
            "{what}: sweep {a} vs by hand {b}"
        )
    };
    close(f(at_ell1, "rms_rad"), mean, "mean");
    close(f(at_ell1, "rms_rad_std"), sd, "std");
    close(f(at_ell1, "rms_rad_ci95_lo"), mean - half, "ci lo");
    close(f(at_ell1, "rms_rad_ci95_hi"), mean + half, "ci hi");
    // The round-off twin ran (of the first seed that ended ok): a finite spread.
    let ro = f(at_ell1, "rms_rad_roundoff");
    assert!((0.0..=1.0).contains(&ro), "{ro}");

    // The report shows the interval; the RMS figure draws error bars: a bar and two caps, three
    // <line> elements, per point (the same figure without repeats has 2 <line> elements).
    let report = std::fs::read_to_string(out.join("report.md")).unwrap();
    assert!(report.contains("Each point ran 3 times"), "{report}");
    assert!(report.contains(" ±"), "{report}");
    let svg = std::fs::read_to_string(out.join("rms_vs_tde_delay.svg")).unwrap();
    let lines = svg.matches("<line").count();
    assert!(
        lines >= 2 + 2 * 3,
        "error bars missing: {lines} <line> elements"
    );
}
