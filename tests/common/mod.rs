//! Helpers shared by the end-to-end tests.
#![allow(dead_code)]

use iceoryx2::node::NodeView;
use iceoryx2::prelude::*;
pub mod python;

#[allow(unused_imports)]
pub use deltaloop_supervisor::record::{FaultKind, RunStatus};
use serde_json::Value;
use std::path::Path;
use std::process::{Command, Output};

/// Runs `deltaloop` with `args` from the repository root.
pub fn deltaloop(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_deltaloop"))
        .args(args)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .expect("deltaloop runs")
}

/// `deltaloop <args>` started from the repository root, output captured.
pub fn spawn(args: &[&str]) -> std::process::Child {
    Command::new(env!("CARGO_BIN_EXE_deltaloop"))
        .args(args)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("deltaloop starts")
}

/// Waits for `child` at most `limit`; kills it (and fails) if it takes longer.
pub fn finish_within(
    mut child: std::process::Child,
    limit: std::time::Duration,
    what: &str,
) -> Output {
    let t0 = std::time::Instant::now();
    while child.try_wait().unwrap().is_none() {
        if t0.elapsed() > limit {
            let _ = child.kill();
            let _ = child.wait();
            panic!("{what}: still running after {limit:?}");
        }
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    child.wait_with_output().unwrap()
}

/// Asserts exit 1 with exactly one line on stderr, no panic; returns that line.
pub fn one_line_error(out: &Output) -> String {
    let err = String::from_utf8_lossy(&out.stderr).into_owned();
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert_eq!(err.lines().count(), 1, "not one line: {err:?}");
    assert!(!err.contains("panicked"), "{err}");
    err.trim_end().to_string()
}

/// Makes a FIFO (named pipe) at `path`.
pub fn mkfifo(path: &Path) {
    let c = std::ffi::CString::new(path.to_str().unwrap()).unwrap();
    // SAFETY: a valid NUL-terminated path; mkfifo only reads it.
    assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0, "mkfifo");
}

/// Process ids of `deltaloop-plant`/`deltaloop-controller` whose command line mentions `needle`.
pub fn children_mentioning(needle: &str) -> Vec<u32> {
    let mut found = Vec::new();
    for entry in std::fs::read_dir("/proc").unwrap().flatten() {
        let Ok(pid) = entry.file_name().to_string_lossy().parse::<u32>() else {
            continue;
        };
        let Ok(cmd) = std::fs::read(entry.path().join("cmdline")) else {
            continue;
        };
        let cmd = String::from_utf8_lossy(&cmd);
        if (cmd.contains("deltaloop-plant") || cmd.contains("deltaloop-controller"))
            && cmd.contains(needle)
        {
            found.push(pid);
        }
    }
    found
}

/// iceoryx2 nodes and services whose name carries `run_id`.
pub fn iceoryx_leftovers(run_id: &str) -> Vec<String> {
    let config = Config::default();
    let mut left = Vec::new();
    Node::<ipc::Service>::list(&config, |state| {
        let name = match &state {
            NodeState::Alive(v) => v.details().as_ref().map(|d| d.name().to_string()),
            NodeState::Dead(v) => v.details().as_ref().map(|d| d.name().to_string()),
            _ => None,
        };
        if let Some(n) = name.filter(|n| n.contains(run_id)) {
            left.push(format!("node {n}"));
        }
        CallbackProgression::Continue
    })
    .unwrap();
    ipc::Service::list(&config, |s| {
        let name = s.static_details.name().to_string();
        if name.contains(run_id) {
            left.push(format!("service {name}"));
        }
        CallbackProgression::Continue
    })
    .unwrap();
    left
}

/// `deltaloop run <config> --mode <mode> --out <out> <extra…>`, asserted to succeed; its summary.json.
pub fn run(config: &str, mode: &str, out: &Path, extra: &[&str]) -> Value {
    let mut args = vec![
        "run",
        config,
        "--mode",
        mode,
        "--out",
        out.to_str().unwrap(),
    ];
    args.extend_from_slice(extra);
    let o = deltaloop(&args);
    assert!(
        o.status.success(),
        "{mode} run failed: {}\n{}",
        String::from_utf8_lossy(&o.stderr),
        String::from_utf8_lossy(&o.stdout)
    );
    summary(out)
}

/// No child process and no iceoryx2 node or service of the run is left.
pub fn assert_clean(out: &Path, summary: &Value) {
    assert!(
        children_mentioning(out.to_str().unwrap()).is_empty(),
        "child processes outlived the run"
    );
    let ids = summary["run_ids"]
        .as_object()
        .expect("process runs record their run ids");
    assert!(!ids.is_empty());
    for id in ids.values() {
        let left = iceoryx_leftovers(id.as_str().unwrap());
        assert!(left.is_empty(), "iceoryx2 resources left behind: {left:?}");
    }
}

/// A JSON file, parsed.
pub fn json(p: &Path) -> Value {
    serde_json::from_str(&std::fs::read_to_string(p).unwrap()).unwrap()
}

/// A run folder's summary.json, parsed.
pub fn summary(dir: &Path) -> Value {
    json(&dir.join("summary.json"))
}

/// The max-joint RMS tracking error (rad) of `law` in a summary.
pub fn max_joint_rms(summary: &Value, law: &str) -> f64 {
    summary["laws"][law]["rms_rad"]
        .as_array()
        .unwrap_or_else(|| panic!("no rms_rad of {law}"))
        .iter()
        .map(|v| v.as_f64().unwrap())
        .fold(0.0, f64::max)
}

/// How `law` ended, as its summary says: the typed `status` and, for a fault, its `fault_kind`.
pub fn outcome(summary: &Value, law: &str) -> (RunStatus, Option<FaultKind>) {
    let m = &summary["laws"][law];
    let status = serde_json::from_value(m["status"].clone())
        .unwrap_or_else(|e| panic!("status of {law}: {e}: {m}"));
    let kind = serde_json::from_value(m["fault_kind"].clone())
        .unwrap_or_else(|e| panic!("fault_kind of {law}: {e}: {m}"));
    (status, kind)
}

/// A long run of `law` in `out` completed with every tick on disk and nothing lost on any stream;
/// returns its peak RSS (MiB) of supervisor, plant and controller.
pub fn assert_complete_and_kept(summary: &Value, out: &Path, law: &str) -> [f64; 3] {
    let rss = assert_complete(summary, out, law);
    let m = &summary["laws"][law];
    let f = std::fs::File::open(out.join("trace.csv")).unwrap();
    let lines = std::io::BufRead::lines(std::io::BufReader::new(f)).count() as u64;
    assert_eq!(
        lines,
        m["ticks"].as_u64().unwrap() + 2,
        "header + ticks 0..=N"
    );
    rss
}

/// `law` ran every tick the scenario planned (0..=N) and the supervisor saw every message of
/// each: the summary says so, and the round-trip interval log on disk holds N + 1 round trips.
/// Each process's peak memory (MiB: supervisor, plant, controller).
pub fn assert_complete(summary: &Value, out: &Path, law: &str) -> [f64; 3] {
    let m = &summary["laws"][law];
    assert_eq!(outcome(summary, law), (RunStatus::Ok, None), "{m}");
    assert_eq!(m["lost_ticks"], 0, "{m}");
    assert_eq!(m["ticks"], summary["ticks"], "{m}");
    let t = &summary["timing"][law];
    let lost = &t["supervisor_lost_samples"];
    for stream in ["state", "torque", "telemetry"] {
        assert_eq!(lost[stream], 0, "{lost}");
    }
    let ticks = m["ticks"].as_u64().unwrap() + 1;
    assert_eq!(t["ticks"], ticks, "{t}");
    assert_eq!(t["round_trip"]["count"], ticks, "{t}");
    let log = out.join(format!("{law}.round_trip.hlog"));
    let logged: u64 = deltaloop_supervisor::timing::hlog::read(&log)
        .unwrap()
        .intervals
        .iter()
        .map(|iv| iv.hist.len())
        .sum();
    assert_eq!(logged, ticks, "round trips in {}", log.display());
    let rss = &t["peak_rss_mib"];
    ["supervisor", "plant", "controller"].map(|w| rss[w].as_f64().unwrap())
}

/// Each process's peak memory in the long run is at most 1.2× the short run's, or at most 10 MiB
/// more: a process's peak includes the pages of fixed-size shared-memory segments (≈ 19 MiB per
/// run in all) that it touches as its queues fill, which depends on how far the load lets it fall
/// behind, not on the run's length. Growth per tick would show as hundreds of MiB here.
pub fn assert_memory_flat(short: [f64; 3], long: [f64; 3]) {
    for (i, who) in ["supervisor", "plant", "controller"].iter().enumerate() {
        assert!(
            long[i] <= 1.2 * short[i] || long[i] - short[i] <= 10.0,
            "{who}: {} MiB in the long run vs {} MiB",
            long[i],
            short[i]
        );
    }
}

/// Every wire type with its fields in declaration order, each passed to the macro `$m` as
/// `$m!(Type { field, … })`; a `Vec` of the results. The one list the layout tests share.
#[allow(unused_macros)]
macro_rules! wire_types {
    ($m:ident) => {
        vec![
            $m!(StateMsg {
                tick,
                flags,
                _pad,
                q,
                qd,
                tau_applied,
                q_true,
                qd_true,
                t_deadline_ns,
                t_wake_ns,
                t_publish_ns,
                t_poll_until_ns
            }),
            $m!(TorqueMsg {
                tick,
                skipped,
                tau,
                s,
                n_hat,
                u,
                t_state_rx_ns,
                t_publish_ns,
                t_poll_until_ns
            }),
            $m!(TelemetryMsg {
                tick,
                flags,
                _pad,
                t_deadline_ns,
                t_wake_ns,
                t_state_pub_ns,
                t_torque_rx_ns,
                late_dropped,
                misses,
                arrival_ns
            }),
            $m!(ControlMsg {
                kind,
                from,
                tick,
                ticks,
                q0,
                t0_ns,
                text
            }),
            $m!(RefSample { tick, q, qd, qdd }),
        ]
    };
}
#[allow(unused_imports)]
pub(crate) use wire_types;
