//! A process run's timing files as other tools read them: the per-second HdrHistogram interval
//! logs (`<law>.<quantity>.hlog`) through HdrHistogram's own Python package (`hdrh`, pinned in
//! python/requirements.txt), checked against `summary.json` and the `.hgrm`; the latency figures
//! and their place in `report.md`.

use crate::common;

use common::python::{python, run_cmd, text};
use common::run;
use serde_json::Value;
use std::process::Command;

/// Reads every interval of each `.hlog` named on the command line with `HistogramLogReader`, adds
/// them up and prints, per file: the intervals' (start, end) in s since the log's StartTime, the
/// total count, min, max, its own p50, and the values at ranks ⌈q·count⌉ for q in QS (the rank
/// rule of the Rust crate, which `summary.json` uses; the Python package rounds the rank instead,
/// which can pick a neighbouring value deep in the tail).
const READ_HLOGS: &str = r#"
import json, math, sys
from hdrh.histogram import HdrHistogram
from hdrh.log import HistogramLogReader
QS = [0.5, 0.99, 0.999]
out = {}
for path in sys.argv[1:]:
    new = lambda: HdrHistogram(1, 100_000_000_000, 3)
    reader = HistogramLogReader(path, new())
    total, spans = new(), []
    while True:
        h = reader.get_next_interval_histogram()
        if h is None:
            break
        start = reader.get_start_time_sec()
        spans.append([h.get_start_time_stamp() / 1e3 - start, h.get_end_time_stamp() / 1e3 - start])
        total.add(h)
    n = total.get_total_count()
    at_rank = []
    for q in QS:
        rank, seen = max(1, math.ceil(q * n)), 0
        for it in total.get_recorded_iterator():
            seen += it.count_at_value_iterated_to
            if seen >= rank:
                at_rank.append(it.value_iterated_to)
                break
    out[path] = dict(start_time=reader.get_start_time_sec(), spans=spans, count=n,
                     min=total.get_min_value(), max=total.get_max_value(),
                     p50=total.get_value_at_percentile(50), at_rank=at_rank)
print(json.dumps(out))
"#;

/// Equal within HdrHistogram's precision at 3 significant digits: values in one bucket differ by
/// less than 1/1024 of the value (the two libraries may report a bucket's lowest or highest
/// equivalent value).
fn same_within_precision(a_ns: f64, b_ns: f64) -> bool {
    (a_ns - b_ns).abs() <= a_ns.abs().max(b_ns.abs()) / 1024.0 + 1.0
}

/// The text elements of an SVG, trimmed.
fn svg_texts(svg: &str) -> Vec<String> {
    svg.split("<text")
        .skip(1)
        .filter_map(|t| {
            let body = &t[t.find('>')? + 1..];
            Some(body[..body.find("</text>")?].trim().to_string())
        })
        .collect()
}

#[test]
fn hlogs_read_back_with_hdrhistogram_python_and_figures_are_embedded() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("run");
    // 0.8 s of motion + 1.5 s hold: ticks 0..=7667, 2.3 s of run time, three intervals.
    let s = run(
        "configs/s1-nominal.toml",
        "lockstep",
        &out,
        &["--law", "tdc", "--hold-s", "1.5"],
    );
    let timing = &s["timing"]["tdc"];
    let ticks = timing["ticks"].as_u64().unwrap();
    assert_eq!(ticks, 7668, "{timing}");

    let names = ["round_trip", "state_to_controller", "controller_compute"];
    let paths: Vec<String> = names
        .iter()
        .map(|n| out.join(format!("tdc.{n}.hlog")).display().to_string())
        .collect();
    let o = run_cmd(
        Command::new(python()).args(["-c", READ_HLOGS]).args(&paths),
        "read the .hlog files",
    );
    assert!(o.status.success(), "python: {}", text(&o.stderr));
    let read: Value = serde_json::from_str(&text(&o.stdout)).unwrap();
    for (name, path) in names.iter().zip(&paths) {
        let r = &read[path.as_str()];
        let want = &timing[*name];
        let count = want["count"].as_u64().unwrap();
        assert!(count > ticks - 20, "{name}: {want}");
        assert_eq!(r["count"].as_u64(), Some(count), "{name}: total count");
        // The .hgrm says the same total.
        let hgrm = std::fs::read_to_string(out.join(format!("tdc.{name}.hgrm"))).unwrap();
        assert!(
            hgrm.contains(&format!("Total count    = {count:>12}")),
            "{name}: {hgrm}"
        );
        // One interval per second of run time (k·Ts), from the log's StartTime; the last one
        // ends with the run.
        assert!(r["start_time"].as_f64().unwrap() > 1.7e9, "{name}: {r}");
        let spans: Vec<(f64, f64)> = r["spans"]
            .as_array()
            .unwrap()
            .iter()
            .map(|s| (s[0].as_f64().unwrap(), s[1].as_f64().unwrap()))
            .collect();
        let end = ticks as f64 * 3e-4;
        let want_spans = [(0.0, 1.0), (1.0, 2.0), (2.0, end)];
        assert_eq!(spans.len(), 3, "{name}: {spans:?}");
        for (g, w) in spans.iter().zip(want_spans) {
            assert!(
                (g.0 - w.0).abs() < 2e-3 && (g.1 - w.1).abs() < 2e-3,
                "{name}: {spans:?}"
            );
        }
        let us = |k: &str| want[k].as_f64().unwrap() * 1e3;
        let ranked = r["at_rank"].as_array().unwrap();
        for (i, key) in ["p50_us", "p99_us", "p999_us"].iter().enumerate() {
            let got = ranked[i].as_f64().unwrap();
            assert!(
                same_within_precision(got, us(key)),
                "{name} {key}: hlog {got} ns, summary {} ns",
                us(key)
            );
        }
        let p50 = r["p50"].as_f64().unwrap();
        assert!(
            same_within_precision(p50, us("p50_us")),
            "{name} p50: {p50}"
        );
        let max = r["max"].as_f64().unwrap();
        assert!(
            same_within_precision(max, us("max_us")),
            "{name} max: {max}"
        );
        assert!(r["min"].as_f64().unwrap() <= p50);
    }

    // Figures: both formats; lockstep measures no wake lateness and has no budget, so neither is
    // drawn; the percentile axis runs to 99.999 %.
    for fig in ["latency", "timeline"] {
        let png = std::fs::read(out.join(format!("tdc.{fig}.png"))).unwrap();
        assert_eq!(&png[1..4], b"PNG", "tdc.{fig}.png");
        let width = u32::from_be_bytes(png[16..20].try_into().unwrap());
        assert!(width >= 1000, "tdc.{fig}.png is {width} px wide");
        let svg = std::fs::read_to_string(out.join(format!("tdc.{fig}.svg"))).unwrap();
        assert!(svg.contains("round trip"), "tdc.{fig}.svg");
        assert!(!svg.contains("wake lateness"), "tdc.{fig}.svg");
        assert!(!svg.contains("torque budget"), "tdc.{fig}.svg");
    }
    let svg = std::fs::read_to_string(out.join("tdc.latency.svg")).unwrap();
    let texts = svg_texts(&svg);
    for label in ["0%", "90%", "99%", "99.9%", "99.99%", "99.999%"] {
        assert!(
            texts.iter().any(|t| t == label),
            "no axis label {label}: {texts:?}"
        );
    }
    assert!(
        svg.contains("round trip: p50 "),
        "the legend gives the percentiles"
    );
    let report = std::fs::read_to_string(out.join("report.md")).unwrap();
    assert!(report.contains("![`tdc` latency by percentile](tdc.latency.png)"));
    assert!(report.contains("![`tdc` latency over run time](tdc.timeline.png)"));
}

/// A run killed outright (SIGKILL) leaves its completed seconds in the interval logs: whole
/// one-second intervals from 0 s, each with the round trip of every tick of its second.
#[test]
fn a_killed_run_leaves_its_completed_intervals() {
    use std::process::Stdio;
    use std::time::{Duration, Instant};
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("killed");
    let mut child = Command::new(env!("CARGO_BIN_EXE_deltaloop"))
        .args(["run", "configs/s1-nominal.toml", "--mode", "lockstep"])
        .args(["--law", "tdc", "--hold-s", "120", "--out"])
        .arg(&out)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let log = out.join("tdc.round_trip.hlog");
    let intervals = || {
        std::fs::read_to_string(&log)
            .map(|t| {
                t.lines()
                    .filter(|l| l.starts_with(|c: char| c.is_ascii_digit()))
                    .count()
            })
            .unwrap_or(0)
    };
    let until = Instant::now() + Duration::from_secs(60);
    while intervals() < 3 && Instant::now() < until {
        std::thread::sleep(Duration::from_millis(20));
    }
    for p in common::children_mentioning(out.to_str().unwrap()) {
        // SAFETY: signalling processes we found by their command line.
        unsafe { libc::kill(p as i32, libc::SIGKILL) };
    }
    // SAFETY: as above, our own child.
    unsafe { libc::kill(child.id() as i32, libc::SIGKILL) };
    let _ = child.wait();
    let read = deltaloop_timing::hlog::read(&log).unwrap();
    assert!(
        read.intervals.len() >= 3,
        "{} intervals",
        read.intervals.len()
    );
    for (i, iv) in read.intervals.iter().enumerate() {
        assert_eq!((iv.start_s, iv.length_s), (i as f64, 1.0), "interval {i}");
        // 3333 or 3334 ticks per second at Ts = 0.3 ms; a loaded machine may make the supervisor
        // lose a few samples, never add any.
        let n = iv.hist.len();
        assert!((3300..=3334).contains(&n), "interval {i}: {n} round trips");
    }
}
