//! Messages and monitors, end to end: what a misbehaving child prints reaches the terminal and
//! the run folder as one bounded, escaped line; a child killed by SIGBUS is named; a killed
//! `top` does not keep the run's observer slot; nothing outlives a killed parent; a soak that
//! diverged says so; `python -m deltaloop.dask` without its extras says what to install.

use crate::common;

use common::{FaultKind, RunStatus, children_mentioning, deltaloop, outcome, summary};
use std::io::BufRead;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

const BIN: &str = env!("CARGO_BIN_EXE_deltaloop");
const ROOT: &str = env!("CARGO_MANIFEST_DIR");

/// S1 plus a hold, one law, realtime in a fair layout (unpinned, SCHED_OTHER: tests run in
/// parallel), a 300-tick silence window.
fn config(dir: &Path, hold_s: f64) -> String {
    let p = dir.join("cfg.toml");
    std::fs::write(
        &p,
        format!(
            "name = \"msg\"\n[scenario]\npath = \"s1\"\nhold_s = {hold_s}\n[controller]\nlaws = [\"tdc\"]\n[faults]\ncontroller_silence_ticks = 300\n[loop.realtime]\nplant_cpu = -1\ncontroller_cpu = -1\nsupervisor_cpu = -1\nplant_priority = 0\ncontroller_priority = 0\nwake_early_us = 0\nlock_memory = false\n"
        ),
    )
    .unwrap();
    p.display().to_string()
}

/// A shell script in `dir`.
fn script(dir: &Path, name: &str, body: &str) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, format!("#!/bin/sh\n{body}\n")).unwrap();
    p
}

fn spawn(args: &[&str]) -> Child {
    Command::new(BIN)
        .args(args)
        .current_dir(ROOT)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap()
}

/// Every process (not only the loop's) whose command line contains `needle`.
fn processes_mentioning(needle: &str) -> Vec<u32> {
    std::fs::read_dir("/proc")
        .unwrap()
        .flatten()
        .filter_map(|e| {
            let pid = e.file_name().to_string_lossy().parse::<u32>().ok()?;
            let cmd = std::fs::read(e.path().join("cmdline")).ok()?;
            String::from_utf8_lossy(&cmd)
                .contains(needle)
                .then_some(pid)
        })
        .filter(|&p| p != std::process::id())
        .collect()
}

/// Waits until `ok` holds, for at most `secs`.
fn wait_until(secs: u64, what: &str, mut ok: impl FnMut() -> bool) {
    let end = Instant::now() + Duration::from_secs(secs);
    while !ok() {
        assert!(Instant::now() < end, "{what} within {secs} s");
        std::thread::sleep(Duration::from_millis(50));
    }
}

fn kill(pid: u32, sig: i32) {
    // SAFETY: signalling a process this test started or found by its command line.
    unsafe { libc::kill(pid as i32, sig) };
}

/// Regression: one non-UTF-8 byte blanked the quoted reason, a child that printed 20 000 lines
/// made a 20 MB message, and a peer's escape codes (clear screen) reached the terminal and the
/// run folder. Now: the reason is one escaped, lossily decoded line; the terminal gets the last
/// lines of each log only; nothing raw reaches summary.json or report.md.
#[test]
fn regression_a_chatty_child_with_escape_codes_and_bad_utf8_is_quoted_bounded_and_escaped() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("run");
    let ctrl = Path::new(BIN).with_file_name("deltaloop-controller");
    // The real controller in the background; after 1 s the wrapper (the controller the
    // supervisor watches) floods its stderr, says its last word with a bad byte and a clear
    // screen, kills the controller and exits 3.
    let wrapper = script(
        tmp.path(),
        "ctl.sh",
        &format!(
            "{} \"$@\" &\npid=$!\nsleep 1\nseq 1 20000 | sed 's/^/chatter line /' >&2\nprintf 'boom \\377 \\033[2J\\033[H cleared\\n' >&2\nkill -9 $pid\nexit 3",
            ctrl.display()
        ),
    );
    let o = deltaloop(&[
        "run",
        &config(tmp.path(), 20.0),
        "--mode",
        "realtime",
        "--controller-cmd",
        &format!("sh {}", wrapper.display()),
        "--out",
        out.to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    let said = "boom \u{fffd} \\u{1b}[2J\\u{1b}[H cleared";
    assert!(
        err.contains(&format!("the controller exited with status 3 ({said})")),
        "{err}"
    );
    assert!(
        !o.stderr.contains(&0x1b),
        "an escape code reached the terminal"
    );
    assert!(o.stderr.len() < 8_000, "{} bytes on stderr", o.stderr.len());
    let s = summary(&out);
    // Exit status 3: the controller's set-up failed.
    assert_eq!(
        outcome(&s, "tdc"),
        (RunStatus::Fault, Some(FaultKind::Setup))
    );
    // What is tested here is the wording: the peer's text, escaped, in the summary too.
    let fault = s["laws"]["tdc"]["fault"].as_str().unwrap();
    assert!(fault.contains(said), "{fault}");
    for f in ["summary.json", "report.md"] {
        let text = std::fs::read_to_string(out.join(f)).unwrap();
        assert!(!text.contains('\u{1b}'), "an escape code reached {f}");
        assert!(text.contains("\\u{1b}[2J"), "{f} lacks the escaped reason");
    }
    assert!(children_mentioning(out.to_str().unwrap()).is_empty());
}

/// Regression: a controller that printed 20 000 lines before it failed to start made the
/// "one-line" error carry all of them (20 MB for long lines). Now the error quotes its last line.
#[test]
fn regression_a_child_that_floods_stderr_before_ready_gives_a_one_line_error() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("run");
    let ctl = script(
        tmp.path(),
        "ctl.sh",
        "seq 1 20000 | sed 's/^/chatter line /' >&2\nprintf 'cannot start: \\377 \\033[31mred\\n' >&2\nexit 3",
    );
    let o = deltaloop(&[
        "run",
        &config(tmp.path(), 0.0),
        "--mode",
        "lockstep",
        "--controller-cmd",
        &format!("sh {}", ctl.display()),
        "--out",
        out.to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert_eq!(err.lines().count(), 1, "{err}");
    assert!(err.len() < 2_000, "{} bytes: {err}", err.len());
    assert!(
        err.contains(&format!(
            "controller exited with status 3 before the run started: the controller: cannot start: \u{fffd} \\u{{1b}}[31mred (log: {})",
            out.join("tdc.controller.log").display()
        )),
        "{err}"
    );
    assert!(!err.contains("chatter line"), "{err}");
}

/// Regression: a plant killed by SIGBUS (what a full /dev/shm does) was reported as a bare
/// "signal 7", and the run said "the laws that finished are kept in …" though none had.
#[test]
fn regression_a_plant_killed_by_sigbus_is_named_and_the_run_says_what_it_kept() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("run");
    let plant = script(tmp.path(), "plant.sh", "kill -BUS $$");
    let o = deltaloop(&[
        "run",
        &config(tmp.path(), 0.0),
        "--mode",
        "lockstep",
        "--plant-cmd",
        &format!("sh {}", plant.display()),
        "--out",
        out.to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(
        err.contains("plant was killed by SIGBUS (signal 7: a bus error, most likely shared memory (/dev/shm) ran out"),
        "{err}"
    );
    assert!(!err.contains("the laws that finished"), "{err}");
    assert!(
        err.contains(&format!(
            "no law finished: {} holds the resolved config.toml, the children's logs (tdc.controller.log, tdc.plant.log)",
            out.display()
        )),
        "{err}"
    );
    assert!(children_mentioning(out.to_str().unwrap()).is_empty());
}

/// `top --plain RUN_ID`'s first line, or what it said if it could not attach.
fn top_attaches(rid: &str) -> (Child, Result<String, String>) {
    let mut top = spawn(&["top", "--plain", "--interval", "100ms", rid]);
    let mut line = String::new();
    let _ = std::io::BufReader::new(top.stdout.as_mut().unwrap()).read_line(&mut line);
    if line.is_empty() {
        let o = top.wait_with_output().unwrap();
        let why = String::from_utf8_lossy(&o.stderr).into_owned();
        return (spawn(&["--version"]), Err(why));
    }
    (top, Ok(line))
}

/// Regression: after a `deltaloop top` was SIGKILLed, every later `top` on that run was refused
/// ("slot taken by another observer") though none was alive.
#[test]
fn regression_a_sigkilled_top_does_not_keep_the_observer_slot() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("run");
    let mut run = spawn(&[
        "run",
        &config(tmp.path(), 30.0),
        "--mode",
        "realtime",
        "--out",
        out.to_str().unwrap(),
    ]);
    let rid = common::run_id_of(&out, &mut run);
    // The children are up before their services are: until then `top` finds no such run
    // (regression: on a loaded host the first `top` came too early and the test failed there).
    let t0 = std::time::Instant::now();
    let (mut first, said) = loop {
        let (top, said) = top_attaches(&rid);
        match &said {
            Err(why) if why.contains("no live run with id") && t0.elapsed().as_secs() < 20 => {
                std::thread::sleep(std::time::Duration::from_millis(100));
            }
            _ => break (top, said),
        }
    };
    assert!(said.is_ok(), "{said:?}");
    kill(first.id(), libc::SIGKILL);
    let _ = first.wait();
    let (mut second, said) = top_attaches(&rid);
    let attached = said.clone();
    kill(second.id(), libc::SIGTERM);
    let _ = second.wait();
    kill(run.id(), libc::SIGTERM);
    let _ = run.wait();
    let line = attached.unwrap_or_else(|e| panic!("the second top was refused: {e}"));
    assert!(line.contains(&rid) || line.contains('='), "{line}");
}

/// Regression: a supervisor killed outright left a foreign child (one that, unlike the built-in
/// processes, sets no parent-death signal itself: here a Python plant still starting) running.
#[test]
fn regression_a_sigkilled_supervisor_takes_a_foreign_child_with_it() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("run");
    let plant = script(
        tmp.path(),
        "plant.sh",
        "exec python3 -c 'import time; time.sleep(60)' \"$@\"",
    );
    let mut run = spawn(&[
        "run",
        &config(tmp.path(), 30.0),
        "--mode",
        "realtime",
        "--plant-cmd",
        &format!("sh {}", plant.display()),
        "--out",
        out.to_str().unwrap(),
    ]);
    let config = out.join("config.toml").display().to_string();
    wait_until(20, "the foreign plant starts", || {
        processes_mentioning(&config).iter().any(|p| {
            std::fs::read(format!("/proc/{p}/cmdline"))
                .is_ok_and(|c| String::from_utf8_lossy(&c).contains("time.sleep(60)"))
        })
    });
    kill(run.id(), libc::SIGKILL);
    let _ = run.wait();
    wait_until(5, "the children stop with their supervisor", || {
        processes_mentioning(&config).is_empty()
    });
}

fn python3() -> Command {
    let ok = Command::new("python3")
        .arg("--version")
        .output()
        .is_ok_and(|o| o.status.success());
    assert!(
        ok,
        "python3 (≥ 3.11) is needed for this test: install it (apt-get install python3)"
    );
    let mut c = Command::new("python3");
    c.env("PYTHONPATH", Path::new(ROOT).join("python"))
        .current_dir(ROOT);
    c
}

/// Regression: a SIGKILLed Dask worker left its `deltaloop` child (and that one's plant and
/// controller) running as orphans. `deltaloop.dask` starts every `deltaloop` with
/// `DELTALOOP_PARENT_PID`: it stops with its parent.
#[test]
fn regression_a_sigkilled_python_driver_takes_its_deltaloop_with_it() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("run");
    let cfg = config(tmp.path(), 30.0);
    let mut py = python3()
        .args([
            "-c",
            "import sys\nfrom deltaloop.dask import run_deltaloop\nrun_deltaloop(sys.argv[1:])",
            BIN,
            "run",
            &cfg,
            "--mode",
            "realtime",
            "--out",
            out.to_str().unwrap(),
        ])
        .spawn()
        .unwrap();
    common::run_id_of(&out, &mut py);
    kill(py.id(), libc::SIGKILL);
    let _ = py.wait();
    wait_until(
        10,
        "deltaloop and its children stop with their parent",
        || processes_mentioning(out.to_str().unwrap()).is_empty(),
    );
    // deltaloop stopped in order (SIGTERM): the folder holds the run so far.
    wait_until(5, "the run folder is written", || {
        out.join("summary.json").exists()
    });
    assert_eq!(summary(&out)["interrupted"], true);

    // A value that is not a pid, or a parent that is not the one named, is one clear line.
    for (v, says) in [
        ("abc", "DELTALOOP_PARENT_PID = `abc` is not a process id"),
        (
            "1234567",
            "DELTALOOP_PARENT_PID = 1234567, but the parent is process",
        ),
    ] {
        let o = Command::new(BIN)
            .args(["run", &cfg, "--out", tmp.path().join("x").to_str().unwrap()])
            .env("DELTALOOP_PARENT_PID", v)
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success() && err.contains(says), "{err}");
        assert_eq!(err.lines().count(), 1, "{err}");
    }
}

/// Regression: `python -m deltaloop.dask` without its extras ended in a traceback.
#[test]
fn regression_python_dask_without_its_extras_says_what_to_install() {
    let o = python3()
        .args([
            "-c",
            "import sys, runpy\nfor m in ('distributed', 'dask', 'dask_jobqueue', 'cloudpickle'):\n    sys.modules[m] = None\nsys.argv = ['deltaloop.dask', 'configs/delay-sweep.toml', '--scheduler', 'tcp://127.0.0.1:1', '--out', '/nonexistent/x']\nrunpy.run_module('deltaloop.dask', run_name='__main__')",
        ])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert_eq!(
        err.trim(),
        "deltaloop.dask: error: python -m deltaloop.dask needs the `dask` extra, and 'distributed' is not installed: pip install './python[dask]' (from the repository), or pip install -r python/requirements.txt"
    );
}

/// Regression: a soak whose robot diverged ended with a progress line that looked normal, and
/// its (partial) minute printed RSS "?" for children that ran too briefly to be sampled.
#[test]
fn regression_a_diverged_soak_says_so_and_prints_real_rss() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("soak");
    // S2, paper preset, tdc, d = 8 diverges within the motion (tests/e2e/delay_injection.rs).
    let o = deltaloop(&[
        "soak",
        "configs/paper/s2-fast.toml",
        "--mode",
        "lockstep",
        "--law",
        "tdc",
        "--transport-delay",
        "8",
        "--duration",
        "5m",
        "--out",
        out.to_str().unwrap(),
    ]);
    let (stdout, err) = (
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr),
    );
    assert!(o.status.success(), "{err}");
    let s = summary(&out);
    assert_eq!(outcome(&s, "tdc"), (RunStatus::Diverged, None), "{s}");
    let tick = s["laws"]["tdc"]["status_tick"].as_u64().unwrap();
    assert!(
        err.contains(&format!("soak: diverged at tick {tick}, after ")),
        "{err}"
    );
    let minutes: Vec<&str> = stdout
        .lines()
        .filter(|l| l.starts_with("minute "))
        .collect();
    assert!(!minutes.is_empty(), "{stdout}");
    for m in minutes {
        assert!(!m.contains('?') && !m.contains("n/a"), "{m}");
    }
}
