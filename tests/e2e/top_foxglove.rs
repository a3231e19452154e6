//! `deltaloop top --foxglove`: a live run served over Foxglove's WebSocket protocol, watched as
//! Foxglove watches it (examples/foxglove/watch_live.py, the venv's `websockets` and
//! `mcap-ros2-support`). The serving test needs a build with `--features foxglove`:
//! `cargo test --features foxglove --test e2e top_foxglove`.

use crate::common;

use common::deltaloop;

/// An address another machine could reach is refused (the protocol has no authentication), in
/// one line, as a bad flag; a build without the feature says how to get it.
#[test]
fn top_foxglove_refuses_a_network_address_and_says_what_it_needs() {
    let o = deltaloop(&["top", "--foxglove", "0.0.0.0:8765"]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(
        err.contains("`0.0.0.0:8765` is not a loopback address")
            && err.contains("ssh -L 8765:127.0.0.1:8765"),
        "{err}"
    );
    if !cfg!(feature = "foxglove") {
        let o = deltaloop(&["top", "--foxglove"]);
        let err = common::one_line_error(&o);
        assert!(
            err.contains("built without the `foxglove` feature")
                && err.contains("cargo build --release --features foxglove"),
            "{err}"
        );
    }
}

/// A realtime run watched live: the joint states a Foxglove client receives are the trace's
/// rows bit for bit (for every tick it got), every channel of the run's MCAP file is served,
/// and the robot is drawn at about 30 Hz of run time.
#[cfg(feature = "foxglove")]
#[test]
fn top_foxglove_serves_the_runs_channels_bit_for_bit() {
    use common::python::{python, root, run_cmd, text};
    use std::io::BufRead;
    use std::process::Command;
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("run");
    let cfg = tmp.path().join("long.toml");
    std::fs::write(
        &cfg,
        "name = \"long\"\n[scenario]\npath = \"s1\"\nhold_s = 8.0\n[controller]\nlaws = [\"tdc\"]\n",
    )
    .unwrap();
    let mut run = common::spawn(&[
        "run",
        cfg.to_str().unwrap(),
        "--mode",
        "realtime",
        "--out",
        out.to_str().unwrap(),
    ]);
    let rid = common::run_id_of(&out, &mut run);
    // The children exist before their services do: retry while top finds no such run.
    let t0 = std::time::Instant::now();
    let (mut top, url) = loop {
        let mut top = common::spawn(&[
            "top",
            "--plain",
            "--interval",
            "1s",
            &rid,
            "--foxglove",
            "127.0.0.1:0",
        ]);
        let mut line = String::new();
        let _ = std::io::BufReader::new(top.stderr.as_mut().unwrap()).read_line(&mut line);
        if let Some(url) = line.split_whitespace().find(|w| w.starts_with("ws://")) {
            break (top, url.to_string());
        }
        let _ = top.wait();
        assert!(
            t0.elapsed().as_secs() < 20,
            "top --foxglove did not start serving: {line}"
        );
        std::thread::sleep(std::time::Duration::from_millis(200));
    };
    let got = tmp.path().join("joint_states.csv");
    let watch = run_cmd(
        Command::new(python())
            .arg(root().join("examples/foxglove/watch_live.py"))
            .arg(&url)
            .arg("4")
            .arg(&got),
        "watch_live.py",
    );
    let said = text(&watch.stdout);
    assert!(watch.status.success(), "{said}{}", text(&watch.stderr));
    println!("watch_live.py (4 s):\n{said}");
    assert!(run.wait().unwrap().success(), "the run failed");
    let _ = top.wait();
    let count = |topic: &str| -> u64 {
        said.lines()
            .find_map(|l| l.strip_prefix(&format!("{topic} ")))
            .and_then(|v| v.trim().parse().ok())
            .unwrap_or(0)
    };
    let joints = count("/tdc/joint_states");
    assert!(joints > 3_000, "{said}");
    for topic in ["/tdc/control", "/tdc/timing"] {
        assert!(count(topic) * 10 > joints * 9, "{topic}: {said}");
    }
    let scenes = count("/tdc/scene");
    assert!(
        scenes > 0 && scenes * 50 < joints,
        "30 Hz, not every tick: {said}"
    );
    assert!(count("/reference_path") >= 1, "{said}");

    // Every joint state received is the trace's row of its tick, bit for bit.
    let mut trace = csv::Reader::from_path(out.join("trace.csv")).unwrap();
    let header = trace.headers().unwrap().clone();
    let col = |n: &str| header.iter().position(|h| h == n).unwrap();
    let cols: Vec<usize> = ["q", "qdot", "tau_applied"]
        .iter()
        .flat_map(|g| (1..=3).map(move |j| format!("{g}_{j}")))
        .map(|n| col(&n))
        .collect();
    let k_col = col("k");
    let rows: std::collections::HashMap<u64, Vec<u64>> = trace
        .records()
        .map(|r| {
            let r = r.unwrap();
            let bits = cols
                .iter()
                .map(|&c| r[c].parse::<f64>().unwrap().to_bits())
                .collect();
            (r[k_col].parse().unwrap(), bits)
        })
        .collect();
    let mut compared = 0;
    for line in std::fs::read_to_string(&got).unwrap().lines() {
        let f: Vec<u64> = line.split(',').map(|x| x.parse().unwrap()).collect();
        let k = f[0] / 300_000;
        let want = rows
            .get(&k)
            .unwrap_or_else(|| panic!("tick {k} not in the trace"));
        assert_eq!(
            &f[1..],
            &want[..],
            "tick {k}: live joint state != trace row"
        );
        compared += 1;
    }
    assert_eq!(compared, joints);
}
