//! `deltaloop whatif` against what stops it and what it reads: a controller-silence stop is a
//! fault, Ctrl-C and SIGTERM stop it at once with nothing written, a hostile interval log makes
//! it allocate nothing big, and a run folder is trusted no further than `replay` trusts it.

use crate::common;

use common::{deltaloop, json, one_line_error, run};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

const S2: &str = "configs/s2-fast.toml";

fn whatif(out: &Path, extra: &[&str]) -> std::process::Output {
    let mut args = vec!["whatif", S2, "--out", out.to_str().unwrap()];
    args.extend_from_slice(extra);
    deltaloop(&args)
}

fn ok(o: &std::process::Output) -> String {
    assert!(
        o.status.success(),
        "whatif failed: {}{}",
        String::from_utf8_lossy(&o.stderr),
        String::from_utf8_lossy(&o.stdout)
    );
    String::from_utf8_lossy(&o.stdout).into_owned()
}

/// Regression: a constant latency over the torque budget (400 µs, S2's budget is 150 µs) ended
/// every replica by the controller-silence stop, and whatif.json called it `diverged_share` 1
/// (`faulted_share` was always 0); the kept trace's last row read `applied`/`commanded` though
/// its reply was late. The stop is a fault, the row says late and held, and the output names
/// the budget rule.
#[test]
fn regression_whatif_a_controller_silence_stop_is_a_fault_not_a_divergence() {
    let tmp = tempfile::tempdir().unwrap();
    let lat = tmp.path().join("slow.txt");
    std::fs::write(&lat, "400\n").unwrap();
    let out = tmp.path().join("w");
    let o = whatif(
        &out,
        &[
            "--law",
            "tdc",
            "--latency",
            lat.to_str().unwrap(),
            "--replicas",
            "2",
            "--keep-traces",
        ],
    );
    let said = ok(&o);
    let w = json(&out.join("whatif.json"));
    let tdc = &w["laws"]["tdc"];
    assert_eq!(
        (
            tdc["faulted_share"].as_f64(),
            tdc["diverged_share"].as_f64()
        ),
        (Some(1.0), Some(0.0)),
        "{tdc}"
    );
    assert!(
        said.contains("faults.controller_silence_ticks") && said.contains("150 µs"),
        "the budget rule is named: {said}"
    );
    let report = std::fs::read_to_string(out.join("report.md")).unwrap();
    assert!(
        report.contains("faults.controller_silence_ticks"),
        "{report}"
    );
    let trace = std::fs::read_to_string(out.join("traces/0000/trace.csv")).unwrap();
    let header: Vec<&str> = trace.lines().next().unwrap().split(',').collect();
    let last: Vec<&str> = trace.lines().last().unwrap().split(',').collect();
    let col = |name: &str| last[header.iter().position(|h| *h == name).unwrap()];
    assert_eq!(
        (col("reply"), col("drives")),
        ("late", "held"),
        "last row: {last:?}"
    );
}

/// Regression: whatif ignored SIGINT and SIGTERM (only SIGKILL stopped `--replicas 1000000`),
/// and a SIGINT during its first in-process runs cut them short and exited 0 with a wrong ideal.
/// Either signal, early or late, ends it with 130 within a second and no whatif.json.
#[test]
fn regression_whatif_stops_on_sigint_and_sigterm_with_130_and_writes_no_result() {
    let tmp = tempfile::tempdir().unwrap();
    let lat = tmp.path().join("rtt.txt");
    std::fs::write(&lat, "20\n30\n").unwrap();
    let start = |name: &str| {
        let out = tmp.path().join(name);
        let child = common::spawn(&[
            "whatif",
            S2,
            "--law",
            "tdc",
            "--latency",
            lat.to_str().unwrap(),
            "--replicas",
            "1000000",
            "--out",
            out.to_str().unwrap(),
        ]);
        (child, out)
    };
    let (late, late_out) = start("late");
    let (early, early_out) = start("early");
    std::thread::sleep(Duration::from_millis(300));
    // SAFETY: kill sends a signal to our own child.
    unsafe { libc::kill(early.id() as i32, libc::SIGTERM) };
    let t0 = Instant::now();
    let o = common::finish_within(early, Duration::from_secs(5), "whatif after SIGTERM");
    let early_s = t0.elapsed();
    std::thread::sleep(Duration::from_millis(1000));
    unsafe { libc::kill(late.id() as i32, libc::SIGINT) };
    let t0 = Instant::now();
    let l = common::finish_within(late, Duration::from_secs(5), "whatif after SIGINT");
    let late_s = t0.elapsed();
    for (o, s, out, sig) in [
        (&o, early_s, &early_out, "SIGTERM"),
        (&l, late_s, &late_out, "SIGINT"),
    ] {
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(130), "{sig}: {err}");
        assert!(s < Duration::from_secs(1), "{sig}: stopped after {s:?}");
        assert!(
            !out.join("whatif.json").exists(),
            "{sig}: a whatif.json of a cut run"
        );
        assert!(err.contains(sig), "{sig}: {err}");
    }
}

/// Standard base64 of `b` (the interval log's payload encoding).
fn base64(b: &[u8]) -> String {
    const A: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut s = String::new();
    for c in b.chunks(3) {
        let n = (u32::from(c[0]) << 16)
            | (u32::from(*c.get(1).unwrap_or(&0)) << 8)
            | u32::from(*c.get(2).unwrap_or(&0));
        for i in 0..4 {
            if i <= c.len() {
                s.push(A[(n >> (18 - 6 * i) & 63) as usize] as char);
            } else {
                s.push('=');
            }
        }
    }
    s
}

/// An interval log of one interval whose V2 histogram header claims `payload_len` bytes of
/// counts and holds four.
fn hostile_hlog(path: &Path, payload_len: u32) {
    let mut h = Vec::new();
    h.extend(0x1c84_9313u32.to_be_bytes()); // V2, uncompressed
    h.extend(payload_len.to_be_bytes());
    h.extend(0u32.to_be_bytes()); // normalizing offset
    h.extend(3u32.to_be_bytes()); // significant digits
    h.extend(1u64.to_be_bytes()); // lowest
    h.extend(3_600_000_000u64.to_be_bytes()); // highest
    h.extend(1.0f64.to_be_bytes());
    h.extend([2, 2, 2, 2]);
    let text = format!(
        "#hostile; values in ns\n#[Histogram log format version 1.3]\n#[StartTime: 1700000000.000 (seconds since epoch)]\n\"StartTimestamp\",\"Interval_Length\",\"Interval_Max\",\"Interval_Compressed_Histogram\"\n0.000,1.000,0.000,{}\n",
        base64(&h)
    );
    std::fs::write(path, text).unwrap();
}

/// Regression: a 360-byte `.hlog` whose histogram header claimed a 4 GiB payload made whatif
/// allocate 4 GiB (here: abort under a 1 GiB address-space limit). The claim is checked against
/// the bytes there are: one line, exit 1.
#[test]
fn regression_a_hostile_hlog_payload_length_allocates_nothing_big() {
    let tmp = tempfile::tempdir().unwrap();
    let h = tmp.path().join("x.hlog");
    hostile_hlog(&h, 0xFFFF_FF00);
    assert!(std::fs::metadata(&h).unwrap().len() < 400);
    let out = tmp.path().join("w");
    let o = std::process::Command::new("sh")
        .arg("-c")
        .arg("ulimit -v 1048576; exec \"$0\" \"$@\"")
        .arg(env!("CARGO_BIN_EXE_deltaloop"))
        .args([
            "whatif",
            S2,
            "--law",
            "tdc",
            "--latency",
            h.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ])
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .unwrap();
    let e = one_line_error(&o);
    assert!(
        e.contains("x.hlog") && e.contains("payload"),
        "names the file and the claim: {e}"
    );
}

/// A copy of run folder `from` as `name` beside it, its `summary.json`'s mode `was` made `mode`.
fn relabelled(from: &Path, name: &str, was: &str, mode: &str) -> PathBuf {
    let dir = from.with_file_name(name);
    std::fs::create_dir_all(&dir).unwrap();
    for f in ["config.toml", "summary.json", "trace.csv"] {
        std::fs::copy(from.join(f), dir.join(f)).unwrap();
    }
    let s = dir.join("summary.json");
    let text = std::fs::read_to_string(&s).unwrap();
    let (a, b) = (
        format!("\"mode\": \"{was}\""),
        format!("\"mode\": \"{mode}\""),
    );
    assert!(text.contains(&a), "{text}");
    std::fs::write(&s, text.replace(&a, &b)).unwrap();
    dir
}

fn edit_trace(dir: &Path, f: impl FnOnce(&mut Vec<String>)) {
    let p = dir.join("trace.csv");
    let mut lines: Vec<String> = std::fs::read_to_string(&p)
        .unwrap()
        .lines()
        .map(String::from)
        .collect();
    f(&mut lines);
    std::fs::write(&p, lines.join("\n") + "\n").unwrap();
}

/// Regression: whatif took a run folder replay refuses: a deleted or a duplicated row, a record
/// cut short (mid-row or at a row's end), a CONFIG of another scenario with `--as-recorded` (it
/// ran S1's 2668 rows as S2), and a lockstep or in-process folder (no arrivals: "p50 0.0 µs").
/// Each is one line naming the file and what is wrong; a text file of zeros stays a source.
#[test]
fn regression_whatif_refuses_run_folders_replay_would_refuse() {
    let tmp = tempfile::tempdir().unwrap();
    let inproc = tmp.path().join("inproc");
    run(S2, "inproc", &inproc, &["--law", "tdc"]);
    // The in-process run relabelled as realtime: a source whatif reads (its trace carries
    // `arrival_ns` = the transport delay, 0), to edit.
    let good = relabelled(&inproc, "good", "inproc", "realtime");
    let copy = |name: &str| relabelled(&good, name, "realtime", "realtime");
    let deleted = copy("deleted");
    edit_trace(&deleted, |l| {
        l.remove(100);
    });
    let duplicated = copy("duplicated");
    edit_trace(&duplicated, |l| {
        let row = l[100].clone();
        l.insert(100, row);
    });
    let cut_row = copy("cut_row");
    let t = std::fs::read(cut_row.join("trace.csv")).unwrap();
    std::fs::write(cut_row.join("trace.csv"), &t[..t.len() - 1]).unwrap();
    let cut_end = copy("cut_end");
    edit_trace(&cut_end, |l| l.truncate(300));
    let lockstep = relabelled(&good, "lockstep", "realtime", "lockstep");
    for (src, says) in [
        (&inproc, "records no arrival"),
        (&lockstep, "records no arrival"),
        (&deleted, "the run lost ticks 99..99"),
        (&duplicated, "ticks out of order"),
        (&cut_row, "the last row has no line end: the record is cut"),
        (
            &cut_end,
            "has ticks 0..=298 but its run completed ticks 0..=667",
        ),
    ] {
        let out = src.with_extension("w");
        let o = whatif(
            &out,
            &[
                "--law",
                "tdc",
                "--latency",
                src.to_str().unwrap(),
                "--replicas",
                "1",
            ],
        );
        let e = one_line_error(&o);
        assert!(
            e.contains(src.to_str().unwrap()) && e.contains(says),
            "{}: {e}",
            src.display()
        );
        assert!(
            !out.exists(),
            "{}: a refused whatif made its folder",
            src.display()
        );
    }
    // The good one reads, and so does a text file of zeros; S1's CONFIG against the good one
    // with --as-recorded is refused.
    let zeros = tmp.path().join("zeros.txt");
    std::fs::write(&zeros, "0\n0\n0\n").unwrap();
    let (g, z) = (good.to_str().unwrap(), zeros.to_str().unwrap());
    let w = tmp.path().join("w-good");
    ok(&whatif(
        &w,
        &[
            "--law",
            "tdc",
            "--latency",
            g,
            "--latency",
            z,
            "--replicas",
            "1",
        ],
    ));
    assert_eq!(json(&w.join("whatif.json"))["latency"]["ticks"], 668 + 3);
    let o = deltaloop(&[
        "whatif",
        "configs/s1-nominal.toml",
        "--law",
        "tdc",
        "--latency",
        g,
        "--as-recorded",
        "--replicas",
        "1",
        "--out",
        tmp.path().join("w-s1").to_str().unwrap(),
    ]);
    let e = one_line_error(&o);
    assert!(
        e.contains("--as-recorded")
            && e.contains(
                "config.toml has name = \"s2-fast\" where the scenario has \"s1-nominal\""
            ),
        "{e}"
    );
}

/// Regression: `--law tdc --law tdc` ran the law twice and wrote its key twice into
/// whatif.json; `--scale 1e-300 --keep-traces` failed on a 300-character folder name and left
/// `traces/` behind.
#[test]
fn regression_whatif_refuses_a_law_twice_and_names_tiny_scales_short() {
    let tmp = tempfile::tempdir().unwrap();
    let lat = tmp.path().join("rtt.txt");
    std::fs::write(&lat, "20\n").unwrap();
    let l = lat.to_str().unwrap();
    let out = tmp.path().join("twice");
    let o = whatif(&out, &["--law", "tdc", "--law", "tdc", "--latency", l]);
    let e = one_line_error(&o);
    assert!(
        e.contains("--law") && e.contains("tdc") && e.contains("each law at most once"),
        "{e}"
    );
    assert!(!out.exists());
    let out = tmp.path().join("tiny");
    ok(&whatif(
        &out,
        &[
            "--law",
            "tdc",
            "--latency",
            l,
            "--replicas",
            "1",
            "--scale",
            "1e-300",
            "--keep-traces",
        ],
    ));
    let names: Vec<String> = std::fs::read_dir(out.join("traces"))
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    assert!(
        names.iter().all(|n| n.len() <= 24) && names.contains(&"x1e-300".to_string()),
        "{names:?}"
    );
    let w = json(&out.join("whatif.json"));
    assert!(w["scales"]["1e-300"]["tdc"].is_object(), "{}", w["scales"]);
}
