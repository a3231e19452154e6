//! `deltaloop replay`: a run folder re-run in-process reproduces its trace byte for byte, and a
//! damaged folder gets a clear error naming the file and line.

use crate::common;

use common::{deltaloop, run};
use std::path::Path;

fn replay(dir: &Path) -> (Option<i32>, String, String) {
    let o = deltaloop(&["replay", dir.to_str().unwrap()]);
    (
        o.status.code(),
        String::from_utf8_lossy(&o.stdout).into_owned(),
        String::from_utf8_lossy(&o.stderr).into_owned(),
    )
}

/// A lockstep run with a sub-tick transport delay (every interval cut at 45 µs) replays byte for
/// byte, and so does the in-process run of the same scenario; the two traces are the same too.
#[test]
fn lockstep_run_with_a_fractional_delay_replays_byte_for_byte() {
    let tmp = tempfile::tempdir().unwrap();
    let (ls, ip) = (tmp.path().join("ls"), tmp.path().join("ip"));
    let args = [
        "--transport-delay-us",
        "45",
        "--law",
        "tde-is",
        "--law",
        "tdc",
    ];
    run("configs/s2-fast.toml", "lockstep", &ls, &args);
    run("configs/s2-fast.toml", "inproc", &ip, &args);
    for dir in [&ls, &ip] {
        let (code, out, err) = replay(dir);
        assert_eq!(code, Some(0), "{err}");
        assert!(
            out.contains("reproduced byte for byte (1336 rows)"),
            "{out}"
        );
    }
    let trace = |d: &Path| std::fs::read(d.join("trace.csv")).unwrap();
    assert_eq!(trace(&ls), trace(&ip));
    let t = String::from_utf8(trace(&ls)).unwrap();
    let row1: Vec<&str> = t.lines().nth(2).unwrap().split(',').collect();
    assert_eq!(*row1.last().unwrap(), "45000", "arrival_ns = D: {row1:?}");
}

/// A damaged trace is named, with its line: an unknown reply word, a missing tick, a lost column.
#[test]
fn a_damaged_run_folder_gets_a_clear_error() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("run");
    run("configs/s2-fast.toml", "inproc", &dir, &["--law", "tdc"]);
    let trace = dir.join("trace.csv");
    let good = std::fs::read_to_string(&trace).unwrap();
    let lines: Vec<&str> = good.lines().collect();
    let cases: Vec<(String, &str)> = vec![
        (
            lines
                .iter()
                .enumerate()
                .map(|(i, l)| {
                    if i == 10 {
                        l.replace(",applied,", ",maybe,")
                    } else {
                        l.to_string()
                    }
                })
                .collect::<Vec<_>>()
                .join("\n"),
            "line 11: column reply = \"maybe\": expected applied, late, skipped or missed",
        ),
        (
            lines
                .iter()
                .enumerate()
                .filter(|&(i, _)| i != 500)
                .map(|(_, l)| *l)
                .collect::<Vec<_>>()
                .join("\n"),
            "line 501: tick 500 where tick 499 was due",
        ),
        (
            lines[..100].join("\n").replace(",arrival_ns", ""),
            "line 1: no column `arrival_ns`",
        ),
    ];
    for (text, needle) in cases {
        std::fs::write(&trace, text + "\n").unwrap();
        let (code, _, err) = replay(&dir);
        assert_eq!(code, Some(1), "{err}");
        assert_eq!(err.trim().lines().count(), 1, "{err}");
        assert!(
            err.contains("trace.csv") && err.contains(needle),
            "{needle}: {err}"
        );
    }
    // A trace cut short replays as far as it goes; its last row then lacks the next state.
    std::fs::write(&trace, lines[..300].join("\n") + "\n").unwrap();
    let (code, _, err) = replay(&dir);
    assert_eq!(code, Some(1), "{err}");
    assert!(
        err.contains("differs first at line 300 (tick 298), column n_true_1"),
        "{err}"
    );
}
