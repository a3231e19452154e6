//! End-to-end: round-off twins (`--sensitivity`) and the digits they leave each figure.

use crate::common;

use common::{deltaloop, summary};

/// At a 150 µs sub-tick delay the super-twisting law's RMS moves by percents when q(0) moves one
/// ulp (|s|^½ sign(s) is not Lipschitz at 0), `tdc` by round-off only. The spread is the largest
/// over 8 twins (each joint and all together, one ulp up and down: `summary.json` names the
/// count and the median); the table prints it and cuts the sensitive law's figures to the digits
/// that survive it.
#[test]
fn sensitivity_twin_separates_round_off_sensitive_laws() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("run");
    let out = deltaloop(&[
        "run",
        "configs/s1-nominal.toml",
        "--mode",
        "inproc",
        "--transport-delay-us",
        "150",
        "--law",
        "tdc",
        "--law",
        "tdc-is-sta",
        "--sensitivity",
        "--out",
        dir.to_str().unwrap(),
    ]);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let s = summary(&dir);
    let spread = |law: &str, k: &str| s["laws"][law]["sensitivity"][k].as_f64().unwrap();
    assert!(spread("tdc", "rms_rel") <= 1e-9, "{}", s["laws"]["tdc"]);
    let sta = spread("tdc-is-sta", "rms_rel");
    assert!((1e-3..1.0).contains(&sta), "tdc-is-sta rms_rel {sta}");
    for law in ["tdc", "tdc-is-sta"] {
        assert!(spread(law, "twins") >= 6.0, "{}", s["laws"][law]);
        let median = spread(law, "rms_rel_median");
        assert!(median <= spread(law, "rms_rel"), "{}", s["laws"][law]);
    }
    // The twin's own RMS is in the summary and differs from the run's by that spread.
    let run_rms = common::max_joint_rms(&s, "tdc-is-sta");
    let twin_rms = spread("tdc-is-sta", "twin_rms_rad");
    let rel = (run_rms - twin_rms).abs() / run_rms.max(twin_rms);
    assert!(rel <= sta * (1.0 + 1e-12), "{rel} vs {sta}");
    // The table: a round-off column; tdc with 4 digits and `< 1e-9`, tdc-is-sta with fewer and
    // its spread in percent.
    let line = |law: &str| {
        stdout
            .lines()
            .find(|l| l.split_whitespace().next() == Some(law))
            .unwrap_or_else(|| panic!("no {law} line in\n{stdout}"))
            .to_string()
    };
    assert!(stdout.contains("round-off"), "{stdout}");
    let tdc = line("tdc");
    assert!(tdc.contains("< 1e-9"), "{tdc}");
    let rms1 = tdc.split_whitespace().nth(1).unwrap();
    assert_eq!(rms1.split('e').next().unwrap().len(), 5, "4 digits: {tdc}");
    let sta_line = line("tdc-is-sta");
    assert!(sta_line.contains(" %"), "{sta_line}");
    let rms1 = sta_line.split_whitespace().nth(1).unwrap();
    assert!(
        rms1.split('e').next().unwrap().len() < 5,
        "fewer digits: {sta_line}"
    );
    let report = std::fs::read_to_string(dir.join("report.md")).unwrap();
    assert!(
        report.contains("Round-off sensitive: `tdc-is-sta`"),
        "{report}"
    );
}

/// A realtime run's timing is not repeatable: a twin says nothing about round-off there. Refused
/// in one line before anything runs, and no folder is left.
#[test]
fn sensitivity_is_refused_in_realtime() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("run");
    let out = deltaloop(&[
        "run",
        "configs/s1-nominal.toml",
        "--sensitivity",
        "--out",
        dir.to_str().unwrap(),
    ]);
    let err = common::one_line_error(&out);
    assert!(
        err.contains("--sensitivity needs mode inproc or lockstep"),
        "{err}"
    );
    assert!(!dir.exists());
}

/// Regression: a lockstep run cut by a loop fault was compared with its complete twin, and the
/// cut reported as a round-off spread. Only runs that ended by the physics (`ok`, `diverged`)
/// get a twin.
#[test]
fn regression_a_faulted_run_gets_no_round_off_twin() {
    let tmp = tempfile::tempdir().unwrap();
    let cfg = tmp.path().join("panic.toml");
    std::fs::write(
        &cfg,
        "name = \"panic\"\n[scenario]\npath = \"s2\"\n[controller]\nlaws = [\"tdc\"]\n[faults]\ninject = \"panic@100\"\n",
    )
    .unwrap();
    let dir = tmp.path().join("run");
    let out = deltaloop(&[
        "run",
        cfg.to_str().unwrap(),
        "--mode",
        "lockstep",
        "--sensitivity",
        "--out",
        dir.to_str().unwrap(),
    ]);
    assert!(!out.status.success());
    let s = summary(&dir);
    assert_eq!(
        common::outcome(&s, "tdc").0,
        common::RunStatus::Fault,
        "{s}"
    );
    assert!(
        s["laws"]["tdc"].get("sensitivity").is_none(),
        "{}",
        s["laws"]["tdc"]
    );
}

/// Regression: with a plant of one's own the twin ran the built-in plant, and the difference
/// between the two plants was reported as round-off. Refused in one line, nothing written.
#[test]
fn regression_sensitivity_is_refused_with_a_plant_or_controller_of_ones_own() {
    let tmp = tempfile::tempdir().unwrap();
    for flag in ["--plant-cmd", "--controller-cmd"] {
        let dir = tmp.path().join("run");
        let out = deltaloop(&[
            "run",
            "configs/s2-fast.toml",
            "--mode",
            "lockstep",
            flag,
            "/bin/false",
            "--sensitivity",
            "--out",
            dir.to_str().unwrap(),
        ]);
        let err = common::one_line_error(&out);
        assert!(err.contains("plant.command or controller.command"), "{err}");
        assert!(!dir.exists());
    }
}
