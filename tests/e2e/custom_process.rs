//! `[plant] command` / `[controller] command` (and `--plant-cmd` / `--controller-cmd`): any
//! executable runs in place of a built-in process, with the same arguments, and is treated the
//! same; a command that cannot start, or a bad one in the file, gets a clear one-line error.

use crate::common;

use common::{deltaloop, run};

/// The built-in controller, named as a custom command, gives the same trace byte for byte as the
/// default (lockstep): the command gets exactly the arguments the built-in one gets.
#[test]
fn a_custom_command_runs_in_place_of_the_builtin_controller() {
    let tmp = tempfile::tempdir().unwrap();
    let (a, b) = (tmp.path().join("builtin"), tmp.path().join("custom"));
    let ctrl = env!("CARGO_BIN_EXE_deltaloop-controller");
    run("configs/s2-fast.toml", "lockstep", &a, &["--law", "tde-is"]);
    let s = run(
        "configs/s2-fast.toml",
        "lockstep",
        &b,
        &["--law", "tde-is", "--controller-cmd", ctrl],
    );
    let trace = |d: &std::path::Path| std::fs::read(d.join("trace.csv")).unwrap();
    assert_eq!(trace(&a), trace(&b));
    let cfg = std::fs::read_to_string(b.join("config.toml")).unwrap();
    assert!(cfg.contains(&format!("command = [\"{ctrl}\"]")), "{cfg}");
    common::assert_clean(&b, &s);
}

#[test]
fn a_command_that_cannot_start_or_a_bad_one_is_named() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("run");
    let o = deltaloop(&[
        "run",
        "configs/s2-fast.toml",
        "--mode",
        "lockstep",
        "--law",
        "tdc",
        "--plant-cmd",
        "/nonexistent/my-plant --fast",
        "--out",
        out.to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert_eq!(err.trim().lines().count(), 1, "{err}");
    assert!(
        err.contains(
            "cannot start the plant command `/nonexistent/my-plant --fast` (plant.command)"
        ),
        "{err}"
    );
    let cfg = tmp.path().join("bad.toml");
    std::fs::write(
        &cfg,
        "[scenario]\npath = \"s1\"\n[controller]\ncommand = [\"python3\", \"\"]\n",
    )
    .unwrap();
    let o = deltaloop(&["run", cfg.to_str().unwrap(), "--mode", "lockstep"]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(
        err.contains("controller.command") && err.contains("non-empty string"),
        "{err}"
    );
}

/// Regression: a foreign controller showed as the built-in law's name in every table, so a run
/// of `--law tdc --controller-cmd my-ctrl` and one of the built-in `tdc` looked the same. The run
/// now carries a label for the controller that ran (`--controller-label`, or the command's
/// program or script name), shown in the terminal table, summary.json and report.md; the built-in
/// controller has none; a label that is not one printable line is refused naming the key.
#[test]
fn regression_a_foreign_controller_is_labelled_in_tables_summary_and_report() {
    let tmp = tempfile::tempdir().unwrap();
    let ctrl = env!("CARGO_BIN_EXE_deltaloop-controller");
    let cases: [(&str, &[&str], Option<&str>); 3] = [
        ("builtin", &[], None),
        (
            "command",
            &["--controller-cmd", ctrl],
            Some("deltaloop-controller"),
        ),
        (
            "flag",
            &[
                "--controller-cmd",
                ctrl,
                "--controller-label",
                "rig-42 ctrl",
            ],
            Some("rig-42 ctrl"),
        ),
    ];
    for (case, extra, label) in cases {
        let out = tmp.path().join(case);
        let mut args = vec!["--law", "tde-is"];
        args.extend_from_slice(extra);
        let o = common::run_output("configs/s2-fast.toml", "lockstep", &out, &args);
        let stdout = String::from_utf8_lossy(&o.stdout);
        assert!(
            o.status.success(),
            "{case}: {}",
            String::from_utf8_lossy(&o.stderr)
        );
        let s = common::summary(&out);
        let report = std::fs::read_to_string(out.join("report.md")).unwrap();
        match label {
            Some(l) => {
                assert_eq!(s["controller_label"], l, "{case}");
                assert!(
                    stdout.contains(&format!("tde-is ({l})")),
                    "{case}: {stdout}"
                );
                assert!(
                    report.contains(&format!("Controller: `{l}`")),
                    "{case}: {report}"
                );
            }
            None => {
                assert!(s.get("controller_label").is_none(), "{case}: {s}");
                assert!(!stdout.contains("tde-is ("), "{case}: {stdout}");
                assert!(!report.contains("Controller: `"), "{case}");
            }
        }
    }
    // A C controller names itself (dl_run_set_label, said in its READY); --controller-label
    // still wins. (This one fails at tick 200 on purpose: the run is a fault, its files written.)
    if let Some(exe) = common::c_peer("c_controller_faults") {
        let cmd = format!("{} fail@200", exe.display());
        for (case, extra, want) in [
            ("named", vec![], "qp-ctrl v1"),
            ("overridden", vec!["--controller-label", "mine"], "mine"),
        ] {
            let out = tmp.path().join(case);
            let mut args = vec!["--law", "tdc", "--controller-cmd", &cmd];
            args.extend(extra);
            let o = common::run_output("configs/s1-nominal.toml", "lockstep", &out, &args);
            assert_eq!(o.status.code(), Some(1), "{case}");
            assert_eq!(common::summary(&out)["controller_label"], want, "{case}");
        }
    }
    let o = deltaloop(&[
        "run",
        "configs/s2-fast.toml",
        "--mode",
        "lockstep",
        "--controller-label",
        "two\nlines",
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert_eq!(err.trim().lines().count(), 1, "{err}");
    assert!(
        err.contains("controller.label") && err.contains("at most 64 printable characters"),
        "{err}"
    );
}
