//! End-to-end: the `deltaloop` binary on the shipped configs, and its answers to bad input.

use crate::common;

use common::{deltaloop, summary};
use std::path::PathBuf;
use std::process::Output;

fn run_into(config: &str, extra: &[&str]) -> (tempfile::TempDir, PathBuf, Output) {
    let tmp = tempfile::tempdir().unwrap();
    let out_dir = tmp.path().join("run");
    let mut args = vec![
        "run",
        config,
        "--mode",
        "inproc",
        "--out",
        out_dir.to_str().unwrap(),
    ];
    args.extend_from_slice(extra);
    let out = deltaloop(&args);
    (tmp, out_dir, out)
}

#[test]
fn s2_run_writes_a_complete_folder_consistent_with_its_trace() {
    let (_tmp, dir, out) = run_into("configs/s2-fast.toml", &[]);
    assert!(
        out.status.success(),
        "stderr: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let stdout = String::from_utf8_lossy(&out.stdout);
    for law in ["tdc", "tde-is", "tdc-is-sta", "pid"] {
        assert!(
            stdout.lines().any(|l| l.starts_with(law)),
            "table lacks {law}:\n{stdout}"
        );
    }
    for f in ["config.toml", "trace.csv", "summary.json", "report.md"] {
        assert!(
            dir.join(f)
                .metadata()
                .map(|m| m.len() > 100)
                .unwrap_or(false),
            "{f} missing or empty"
        );
    }
    let s = summary(&dir);
    assert_eq!(s["ticks"], 667);
    // Recompute each law's RMS error from trace.csv (rows k = 0..=N) and compare with summary.json.
    let mut rdr = csv::Reader::from_path(dir.join("trace.csv")).unwrap();
    let headers = rdr.headers().unwrap().clone();
    let col = |name: &str| headers.iter().position(|h| h == name).unwrap();
    let (law_c, e_c) = (col("law"), [col("e_1"), col("e_2"), col("e_3")]);
    let mut sums: std::collections::BTreeMap<String, ([f64; 3], usize)> = Default::default();
    for rec in rdr.records() {
        let rec = rec.unwrap();
        let entry = sums.entry(rec[law_c].to_string()).or_insert(([0.0; 3], 0));
        for (i, &c) in e_c.iter().enumerate() {
            let e: f64 = rec[c].parse().unwrap();
            entry.0[i] += e * e;
        }
        entry.1 += 1;
    }
    assert_eq!(sums.len(), 4);
    for (law, (sq, n)) in sums {
        assert_eq!(n, 668, "{law}: rows k = 0..=667");
        for i in 0..3 {
            let rms = (sq[i] / n as f64).sqrt();
            let reported = s["laws"][&law]["rms_rad"][i].as_f64().unwrap();
            assert!(
                (rms - reported).abs() <= 1e-12 * reported,
                "{law} joint {i}: trace {rms} vs summary {reported}"
            );
        }
        for key in [
            "max_abs_err_rad",
            "task_rms_mm",
            "max_abs_tau_nm",
            "torque_tv_nm",
            "hf_torque_share",
            "tde_err_rms",
            "delta_n_max",
            "delta_n_p999",
            "k2_required",
        ] {
            assert!(s["laws"][&law].get(key).is_some(), "{law} lacks {key}");
        }
    }
    // The report's paper-shaped table carries the same numbers.
    let report = std::fs::read_to_string(dir.join("report.md")).unwrap();
    let sta_rms = s["laws"]["tdc-is-sta"]["rms_rad"][0].as_f64().unwrap();
    assert!(
        report.contains("Table III") && report.contains(&format!("{sta_rms:.3e}")),
        "report lacks the RMS table"
    );
    // The resolved config is a valid input with every constant explicit.
    let cfg = std::fs::read_to_string(dir.join("config.toml")).unwrap();
    assert!(
        cfg.contains("m_bar = 0.03") && cfg.contains("k1 = 700.0"),
        "{cfg}"
    );
}

#[test]
fn law_filter_and_paper_preset_report_the_limit_cycle() {
    let (_tmp, dir, out) = run_into("configs/paper/s1-nominal.toml", &["--law", "tdc-is-sta"]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let s = summary(&dir);
    let laws = s["laws"].as_object().unwrap();
    assert_eq!(laws.keys().collect::<Vec<_>>(), ["tdc-is-sta"]);
    assert!(laws["tdc-is-sta"]["clamp_count"].as_u64().unwrap() > 0);
    let report = std::fs::read_to_string(dir.join("report.md")).unwrap();
    assert!(
        report.contains("Why the paper's M̄ misbehaves here")
            && report.contains("Observed limit cycles"),
        "{report}"
    );
}

#[test]
fn bad_inputs_get_clear_errors_and_no_panic() {
    let tmp = tempfile::tempdir().unwrap();
    let bad = tmp.path().join("bad.toml");
    let cases: [(&str, &str); 3] = [
        (
            "[scenario]\npath = \"s1\"\n[controller]\nk1 = -3.0\n",
            "`controller.k1` = -3",
        ),
        (
            "[scenario]\npath = \"s1\"\n[plant]\nfrictoin = true\n",
            "unknown field `frictoin`",
        ),
        ("[scenario]\npath = \"s9\"\n", "s9"),
    ];
    for (text, needle) in cases {
        std::fs::write(&bad, text).unwrap();
        let out = deltaloop(&[
            "run",
            bad.to_str().unwrap(),
            "--mode",
            "inproc",
            "--out",
            tmp.path().join("o").to_str().unwrap(),
        ]);
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "{err}");
        assert!(
            err.contains(needle) && !err.contains("panicked"),
            "want {needle:?} in: {err}"
        );
    }
    let out = deltaloop(&["run", "/no/such/file.toml", "--mode", "inproc"]);
    assert!(String::from_utf8_lossy(&out.stderr).contains("/no/such/file.toml"));
    let out = deltaloop(&["run", "configs/s1-nominal.toml", "--law", "lqr"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2));
    assert!(err.contains("lqr") && err.contains("tdc-is-sta"), "{err}");
}

/// Every law of the enum is named wherever the laws are listed by hand: `run --help`, the law
/// crate's description, the README's controller line and crate map, docs/controllers.md
/// (regression: a fifth law was added and four of these still named four).
#[test]
fn every_law_is_named_wherever_the_laws_are_listed() {
    let root = crate::common::python::root();
    let read = |p: &str| std::fs::read_to_string(root.join(p)).unwrap();
    let readme = read("README.md");
    let line = |text: &str, starts: &str| -> String {
        let i = text.find(starts).unwrap_or_else(|| panic!("no `{starts}`"));
        text[i..].split("\n\n").next().unwrap().replace('\n', " ")
    };
    let help = String::from_utf8_lossy(&deltaloop(&["run", "--help"]).stdout).into_owned();
    let manifest = read("controller/law/Cargo.toml");
    let places = [
        ("run --help", line(&help, "--law <LAWS>")),
        ("controller/law/Cargo.toml", line(&manifest, "description")),
        ("README controller", line(&readme, "- **controller**")),
        ("README crate map", line(&readme, "controller/law/")),
        ("docs/controllers.md", read("docs/controllers.md")),
    ];
    for law in deltaloop_config::Law::ALL {
        let word = format!("{law}");
        for (place, text) in &places {
            let named = text
                .split(|c: char| !(c.is_ascii_alphanumeric() || c == '-'))
                .any(|w| w == word);
            assert!(named, "{place} does not name the law {word}: {text}");
        }
    }
}
