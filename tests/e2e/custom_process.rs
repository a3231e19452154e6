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
