//! `--out` claims: a refused command leaves nothing in the folder (above all no lock file that a
//! later `--force` would take for a deltaloop folder), and no `--out` may be, hold or lie inside
//! a file the command reads, `--force` or not.

use crate::common;

use common::{deltaloop, one_line_error, run};
use std::path::{Path, PathBuf};

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// Every entry of `dir` (hidden ones too), sorted.
fn entries(dir: &Path) -> Vec<PathBuf> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir)
        .unwrap()
        .flatten()
        .map(|e| e.path())
        .collect();
    v.sort();
    v
}

/// Regression: `whatif … --out thesis --force` was refused (not a deltaloop folder), but the
/// refusal left `.deltaloop-lock` in `thesis`, and the same command again emptied it. The same
/// for `run --mode inproc` and `replay --out`. Each is refused without and with `--force`, twice,
/// and the folder holds its one file, untouched, and nothing else.
#[test]
fn regression_a_refused_out_arms_no_force() {
    let tmp = tempfile::tempdir().unwrap();
    let thesis = tmp.path().join("thesis");
    std::fs::create_dir(&thesis).unwrap();
    let tex = thesis.join("thesis.tex");
    std::fs::write(&tex, "\\documentclass{book}").unwrap();
    let lat = tmp.path().join("lat.txt");
    std::fs::write(&lat, "20\n").unwrap();
    let r1 = tmp.path().join("r1");
    run("configs/s1-nominal.toml", "inproc", &r1, &["--law", "tdc"]);
    let cfg = "configs/s1-nominal.toml";
    let commands: [Vec<&str>; 3] = [
        vec!["whatif", cfg, "--latency", s(&lat), "--replicas", "1"],
        vec!["run", cfg, "--mode", "inproc", "--law", "tdc"],
        vec!["replay", s(&r1)],
    ];
    for cmd in commands {
        for force in [false, true, true] {
            let mut args = cmd.clone();
            args.extend(["--out", s(&thesis)]);
            if force {
                args.push("--force");
            }
            let e = one_line_error(&deltaloop(&args));
            let says = if force {
                "does not look like a deltaloop run folder"
            } else {
                "is not empty"
            };
            assert!(e.contains(says), "{args:?}: {e}");
            assert_eq!(entries(&thesis), vec![tex.clone()], "{args:?}");
            assert_eq!(
                std::fs::read_to_string(&tex).unwrap(),
                "\\documentclass{book}"
            );
        }
    }
    // A folder that did not exist is not made by a refused command either.
    let new = tmp.path().join("r1/new");
    let e = one_line_error(&deltaloop(&["replay", s(&r1), "--out", s(&new)]));
    assert!(e.contains("is inside the run folder being replayed"), "{e}");
    assert!(!new.exists());
}

/// Regression: `whatif RUN_A/config.toml --latency RUN_B --out RUN_A --force` emptied run A, the
/// folder its own CONFIG came from. CONFIG is one of what it reads: refused, run A untouched.
#[test]
fn regression_whatif_out_holding_its_config_is_refused() {
    let tmp = tempfile::tempdir().unwrap();
    let a = tmp.path().join("a");
    run("configs/s1-nominal.toml", "inproc", &a, &["--law", "tdc"]);
    let lat = tmp.path().join("lat.txt");
    std::fs::write(&lat, "20\n").unwrap();
    let before = entries(&a);
    let cfg = a.join("config.toml");
    let e = one_line_error(&deltaloop(&[
        "whatif",
        s(&cfg),
        "--latency",
        s(&lat),
        "--replicas",
        "1",
        "--out",
        s(&a),
        "--force",
    ]));
    assert!(
        e.contains("contains the scenario file") && e.contains("config.toml"),
        "{e}"
    );
    assert_eq!(entries(&a), before);
}

/// `run CONFIG --out DIR --force` with CONFIG in DIR (here a run's own config.toml, re-run into
/// its own folder) would empty DIR, CONFIG with it: refused, the folder untouched; the same for
/// a script its controller command names.
#[test]
fn regression_run_out_holding_its_config_is_refused() {
    let tmp = tempfile::tempdir().unwrap();
    let a = tmp.path().join("a");
    run("configs/s1-nominal.toml", "inproc", &a, &["--law", "tdc"]);
    let before = entries(&a);
    let cfg = a.join("config.toml");
    let kept = std::fs::read(&cfg).unwrap();
    for out in [a.clone(), tmp.path().to_path_buf()] {
        let e = one_line_error(&deltaloop(&[
            "run",
            s(&cfg),
            "--mode",
            "inproc",
            "--out",
            s(&out),
            "--force",
        ]));
        assert!(e.contains("contains the scenario file"), "{e}");
        assert_eq!(entries(&a), before);
        assert_eq!(std::fs::read(&cfg).unwrap(), kept);
    }
    // The same for a file its controller command names.
    let script = a.join("ctl.py");
    std::fs::write(&script, "print()").unwrap();
    let ctl = format!("python3 {}", s(&script));
    let e = one_line_error(&deltaloop(&[
        "run",
        "configs/s1-nominal.toml",
        "--mode",
        "lockstep",
        "--controller-cmd",
        &ctl,
        "--out",
        s(&a),
        "--force",
    ]));
    assert!(
        e.contains("contains a file of the controller command"),
        "{e}"
    );
    assert!(script.is_file() && cfg.is_file());
    // A script named by a bare word, from the working directory, is a file the command reads.
    let cfg_abs = concat!(env!("CARGO_MANIFEST_DIR"), "/configs/s1-nominal.toml");
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_deltaloop"))
        .args(["run", cfg_abs, "--mode", "lockstep"])
        .args([
            "--controller-cmd",
            "python3 ctl.py",
            "--out",
            ".",
            "--force",
        ])
        .current_dir(&a)
        .output()
        .unwrap();
    let e = one_line_error(&o);
    assert!(
        e.contains("contains a file of the controller command") && e.contains("ctl.py"),
        "{e}"
    );
    assert!(script.is_file() && cfg.is_file());
}

/// `sweep run SWEEP --base BASE --out DIR --force` with the base copy in DIR: refused, BASE kept.
#[test]
fn regression_sweep_out_holding_its_base_is_refused() {
    let tmp = tempfile::tempdir().unwrap();
    let keep = tmp.path().join("keep");
    std::fs::create_dir(&keep).unwrap();
    let base = keep.join("base.toml");
    std::fs::write(
        &base,
        "[scenario]\npath = \"s1\"\n[controller]\nlaws = [\"tdc\"]\n",
    )
    .unwrap();
    let sweep = tmp.path().join("sw.toml");
    std::fs::write(
        &sweep,
        "name = \"h\"\nbase = \"keep/base.toml\"\nscenarios = [\"s1\"]\npresets = [\"matched\"]\nlaws = [\"tdc\"]\ntde_delay_samples = [1]\ntransport_delay_samples = [0]\n",
    )
    .unwrap();
    for extra in [vec![], vec!["--base", s(&base)]] {
        let mut args = vec!["sweep", "run", s(&sweep), "--out", s(&keep), "--force"];
        args.extend(extra);
        let e = one_line_error(&deltaloop(&args));
        assert!(e.contains("contains the sweep's base config"), "{e}");
        assert_eq!(entries(&keep), vec![base.clone()]);
    }
}
