//! ROS 2 over DDS, tested against an independent DDS implementation: Python nodes on PyPI's
//! `cyclonedds` (Eclipse Cyclone DDS, the library behind ROS 2's rmw_cyclonedds) with the ROS 2
//! types written by hand (`python/deltaloop/ros2.py`, the scripts of `examples/ros2/`), in the
//! tests' venv. Every participant on both sides is pinned to loopback (deltaloop: this host
//! only, its default; Cyclone: interface `lo`, multicast off), each test on a domain of its own.

use crate::common;
use common::python::{python, root, text};
use deltaloop_model::{DeltaRobot, Vec3};
use serde_json::Value;
use std::collections::BTreeMap;
use std::path::Path;
use std::process::{Child, Command, Output, Stdio};
use std::time::{Duration, Instant};

/// `deltaloop <args>` on DDS domain `domain`, ROS 2's other variables unset.
pub(crate) fn deltaloop(domain: u16, args: &[&str]) -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_deltaloop"));
    c.args(args)
        .current_dir(root())
        .env("ROS_DOMAIN_ID", domain.to_string())
        .env_remove("ROS_AUTOMATIC_DISCOVERY_RANGE")
        .env_remove("ROS_LOCALHOST_ONLY")
        .stdout(Stdio::piped())
        .stderr(Stdio::piped());
    c
}

/// The Python node `script` (a path from the repository root) with `args`, in the venv.
pub(crate) fn node(script: &str, args: &[&str]) -> Child {
    Command::new(python())
        .arg(root().join(script))
        .args(args)
        .current_dir(root())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap_or_else(|e| panic!("{script} starts: {e}"))
}

/// Waits for `child` at most `limit`, killing it past that; its output.
pub(crate) fn wait(mut child: Child, limit: Duration, what: &str) -> Output {
    let t0 = Instant::now();
    while child.try_wait().unwrap().is_none() {
        if t0.elapsed() > limit {
            let _ = child.kill();
            let o = child.wait_with_output().unwrap();
            panic!(
                "{what}: still running after {limit:?}\n{}\n{}",
                text(&o.stdout),
                text(&o.stderr)
            );
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    child.wait_with_output().unwrap()
}

fn ok(o: &Output, what: &str) {
    assert!(
        o.status.success(),
        "{what} failed ({}):\n{}\n{}",
        o.status,
        text(&o.stdout),
        text(&o.stderr)
    );
}

/// Until `path` exists (the run folder's config.toml: the run has started).
pub(crate) fn wait_for(path: &Path) {
    let t0 = Instant::now();
    while !path.exists() {
        assert!(
            t0.elapsed() < Duration::from_secs(30),
            "{} never appeared",
            path.display()
        );
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// `run configs/s1-nominal.toml --law tdc --mode realtime --hold-s HOLD --ros2 --out OUT`.
fn live_run(domain: u16, hold_s: &str, out: &Path) -> Command {
    let args = [
        "run",
        "configs/s1-nominal.toml",
        "--law",
        "tdc",
        "--mode",
        "realtime",
    ];
    let mut c = deltaloop(domain, &args);
    c.args(["--hold-s", hold_s, "--ros2", "--out", out.to_str().unwrap()]);
    c
}

/// A float as Python's `float.hex()` writes it, exactly.
fn from_hex(s: &str) -> f64 {
    let (neg, s) = s.strip_prefix('-').map_or((false, s), |r| (true, r));
    let v = match s {
        "inf" => f64::INFINITY,
        "nan" => f64::NAN,
        _ => {
            let s = s.strip_prefix("0x").expect("0x");
            let (m, e) = s.split_once('p').expect("p");
            let (int, frac) = m.split_once('.').unwrap_or((m, ""));
            let digits = u64::from_str_radix(&format!("{int}{frac}"), 16).expect("hex digits");
            let exp = e.parse::<i32>().expect("exponent") - 4 * frac.len() as i32;
            // Two steps: 2^exp alone may leave the range of f64 where the product does not.
            digits as f64 * 2f64.powi(exp / 2) * 2f64.powi(exp - exp / 2)
        }
    };
    if neg { -v } else { v }
}

fn hexes(v: &Value) -> Vec<f64> {
    v.as_array()
        .unwrap()
        .iter()
        .map(|x| from_hex(x.as_str().unwrap()))
        .collect()
}

/// The watcher's lines by topic (ROS name, leading `/`).
fn lines(path: &Path) -> BTreeMap<String, Vec<Value>> {
    let mut by = BTreeMap::<String, Vec<Value>>::new();
    for l in std::fs::read_to_string(path).unwrap().lines() {
        let v: Value = serde_json::from_str(l).unwrap();
        let t = v["topic"].as_str().unwrap();
        let t = format!(
            "/{}",
            t.strip_prefix("rt/").unwrap_or(t).trim_start_matches('/')
        );
        by.entry(t).or_default().push(v);
    }
    by
}

/// trace.csv's rows by tick: column name → value.
fn trace(dir: &Path) -> BTreeMap<u64, BTreeMap<String, String>> {
    let mut r = csv::Reader::from_path(dir.join("trace.csv")).unwrap();
    let h: Vec<String> = r.headers().unwrap().iter().map(String::from).collect();
    r.records()
        .map(|rec| {
            let rec = rec.unwrap();
            let row: BTreeMap<String, String> = h
                .iter()
                .cloned()
                .zip(rec.iter().map(String::from))
                .collect();
            (row["k"].parse().unwrap(), row)
        })
        .collect()
}

fn col3(row: &BTreeMap<String, String>, name: &str) -> Vec<f64> {
    (1..=3)
        .map(|j| row[&format!("{name}_{j}")].parse::<f64>().unwrap())
        .collect()
}

fn bits(v: &[f64]) -> Vec<u64> {
    v.iter().map(|x| x.to_bits()).collect()
}

/// The tick of a stamp at period `ts_ns`.
fn tick(v: &Value, ts_ns: u64) -> u64 {
    let ns = v["sec"].as_u64().unwrap() * 1_000_000_000 + v["nanosec"].as_u64().unwrap();
    assert_eq!(ns % ts_ns, 0, "a stamp off the tick grid: {v}");
    ns / ts_ns
}

/// `run --ros2`, watched by a Cyclone DDS node: every joint state it received equals trace.csv's
/// q, q̇ and τᵃ of that tick bit for bit (and the reference its q_des), the `/tf` pose is the
/// forward kinematics of that q, `/clock` runs on the ticks, `/diagnostics` reports the law and
/// `/rosout` its start and end; nearly every tenth tick arrived.
#[test]
fn ros2_live_topics_equal_the_trace_bit_for_bit() {
    let tmp = tempfile::tempdir().unwrap();
    // The run is realtime: a host that stalls its controller past the budget ends it in a
    // safe stop, which says nothing about the topics; such an attempt is run again.
    common::on_a_noisy_host("ros2_live_topics_equal_the_trace_bit_for_bit", |n| {
        let dir = tmp.path().join(format!("attempt-{n}"));
        std::fs::create_dir_all(&dir).unwrap();
        live_topics_equal_the_trace(&dir)
    });
}

/// One attempt of [`ros2_live_topics_equal_the_trace_bit_for_bit`] in the folder `dir`.
fn live_topics_equal_the_trace(dir: &Path) -> Result<(), String> {
    let domain = 171;
    let (out, seen) = (dir.join("run"), dir.join("watch.jsonl"));
    let d = domain.to_string();
    let watcher = node(
        "examples/ros2/watch.py",
        &[
            "--domain",
            &d,
            "--law",
            "tdc",
            "--out",
            seen.to_str().unwrap(),
            "--idle-s",
            "10",
        ],
    );
    // Discovery before the first tick (the trajectory would come anyway: transient local).
    std::thread::sleep(Duration::from_secs(2));
    let run = live_run(domain, "1.5", &out).output().unwrap();
    ok(
        &wait(watcher, Duration::from_secs(60), "watch.py"),
        "watch.py",
    );
    if !run.status.success() {
        let failed = format!("the run failed ({}): {}", run.status, text(&run.stderr));
        let s = common::summary(&out);
        return common::judge(common::disturbance(&s, "tdc"), Err(failed));
    }
    assert!(
        text(&run.stderr).contains("ROS 2: node /deltaloop on DDS domain 171 (this host only)")
    );

    let rows = trace(&out);
    let by = lines(&seen);
    let ts_ns = 300_000;
    let js = &by["/deltaloop/tdc/joint_states"];
    let expected = rows.keys().filter(|k| *k % 10 == 0).count();
    assert!(
        js.len() * 10 >= expected * 9,
        "{} of {expected} joint states arrived",
        js.len()
    );
    let robot = DeltaRobot::default();
    for m in js {
        let k = tick(m, ts_ns);
        assert_eq!(k % 10, 0, "every 10th tick only");
        let row = &rows[&k];
        assert_eq!(
            m["name"],
            serde_json::json!(["joint_1", "joint_2", "joint_3"])
        );
        assert_eq!(m["frame_id"], "base");
        assert_eq!(
            bits(&hexes(&m["position"])),
            bits(&col3(row, "q")),
            "q at tick {k}"
        );
        assert_eq!(
            bits(&hexes(&m["velocity"])),
            bits(&col3(row, "qdot")),
            "q̇ at tick {k}"
        );
        assert_eq!(
            bits(&hexes(&m["effort"])),
            bits(&col3(row, "tau_applied")),
            "τᵃ at {k}"
        );
    }
    for m in &by["/deltaloop/tdc/reference"] {
        let k = tick(m, ts_ns);
        assert_eq!(
            bits(&hexes(&m["position"])),
            bits(&col3(&rows[&k], "q_des")),
            "q_d at {k}"
        );
    }
    let tf = &by["/tf"];
    assert!(
        tf.len() * 10 >= expected * 9,
        "{} poses of {expected}",
        tf.len()
    );
    for m in tf {
        let t = &m["transforms"][0];
        assert_eq!(t["frame_id"], "base");
        assert_eq!(t["child_frame_id"], "tdc/end_effector");
        let k = tick(t, ts_ns);
        let q = col3(&rows[&k], "q");
        let x = robot.fk(&Vec3::new(q[0], q[1], q[2])).unwrap();
        assert_eq!(
            bits(&hexes(&t["translation"])),
            bits(x.as_slice()),
            "pose at tick {k}"
        );
    }
    let clock: Vec<u64> = by["/clock"].iter().map(|m| tick(m, ts_ns)).collect();
    assert!(
        clock.windows(2).all(|w| w[0] < w[1]),
        "the clock runs forward"
    );
    let diag = &by["/diagnostics"];
    let status = &diag[0]["status"][0];
    assert_eq!(status["name"], "deltaloop/tdc");
    assert!(status["values"]["misses"].is_string(), "{status}");
    let said: Vec<&str> = by["/rosout"]
        .iter()
        .map(|m| m["msg"].as_str().unwrap())
        .collect();
    assert!(said.contains(&"tdc: started"), "{said:?}");
    let last = rows.keys().max().unwrap();
    assert!(
        said.iter()
            .any(|s| s.starts_with(&format!("tdc: ended at tick {last}"))),
        "{said:?}"
    );
    Ok(())
}

/// Starts `--controller ros2` in `mode` on `domain` and the Cyclone node `script` (a tdc
/// controller) against its resolved config; the run's output (the node must end well too).
fn with_dds_controller(
    script: &str,
    domain: u16,
    mode: &str,
    out: &Path,
    extra: &[&str],
) -> Output {
    let mut args = vec![
        "run",
        "configs/s1-ros2.toml",
        "--mode",
        mode,
        "--controller",
        "ros2",
        "--out",
        out.to_str().unwrap(),
    ];
    args.extend_from_slice(extra);
    let run = deltaloop(domain, &args).spawn().unwrap();
    let config = out.join("config.toml");
    wait_for(&config);
    let d = domain.to_string();
    let ctl = node(
        script,
        &[
            "--config",
            config.to_str().unwrap(),
            "--domain",
            &d,
            "--idle-s",
            "2",
        ],
    );
    let run = wait(run, Duration::from_secs(120), "the run");
    let ctl = wait(ctl, Duration::from_secs(60), script);
    ok(&ctl, script);
    run
}

/// The example tdc node.
const CONTROLLER: &str = "examples/ros2/controller.py";

/// trace.csv without the law's internals s and N̂ (a JointState command carries only τ).
fn robot_columns(dir: &Path) -> String {
    let mut r = csv::Reader::from_path(dir.join("trace.csv")).unwrap();
    let h: Vec<String> = r.headers().unwrap().iter().map(String::from).collect();
    let keep: Vec<usize> = (0..h.len())
        .filter(|i| !(h[*i].starts_with("s_") || h[*i].starts_with("n_hat_")))
        .collect();
    let mut s = keep
        .iter()
        .map(|i| h[*i].clone())
        .collect::<Vec<_>>()
        .join(",");
    for rec in r.records() {
        let rec = rec.unwrap();
        s.push('\n');
        s += &keep.iter().map(|i| &rec[*i]).collect::<Vec<_>>().join(",");
    }
    s
}

/// A Cyclone DDS node is the tdc controller over /robot_joint_states → /robot_joint_commands:
/// in lockstep the run is the built-in controller's byte for byte (but for the law's internals,
/// which a command does not carry); in realtime at 1 kHz it completes `ok`, every command judged
/// by the arrival rule.
#[test]
fn ros2_controller_node_closes_the_loop() {
    let tmp = tempfile::tempdir().unwrap();
    let builtin = tmp.path().join("builtin");
    // Through the hold too: the trajectory ends at its first tick, which the node holds.
    let hold = ["--hold-s", "0.3"];
    common::run("configs/s1-ros2.toml", "lockstep", &builtin, &hold);
    let dds = tmp.path().join("dds-lockstep");
    let run = with_dds_controller(CONTROLLER, 172, "lockstep", &dds, &hold);
    ok(&run, "the lockstep run over DDS");
    assert_eq!(robot_columns(&dds), robot_columns(&builtin));
    let s = common::summary(&dds);
    assert_eq!(s["laws"]["tdc"]["status"], "ok", "{s}");
    let log = std::fs::read_to_string(dds.join("tdc.controller.log")).unwrap();
    assert!(log.contains("0 command(s) refused"), "{log}");

    // Realtime at 1 kHz, judged by the run's record: a host that stalled the plant says nothing
    // about the node, and the attempt is run again.
    common::on_a_noisy_host("ros2_controller_node_closes_the_loop", |n| {
        let rt = tmp.path().join(format!("dds-realtime-{n}"));
        let run = with_dds_controller(CONTROLLER, 172, "realtime", &rt, &[]);
        let s = common::summary(&rt);
        if !run.status.success() {
            // A safe stop (a fault: no command within the budget) is the machine's when the
            // record says it disturbed the run.
            let failed = format!("the realtime run over DDS failed: {}", text(&run.stderr));
            return common::judge(common::disturbance(&s, "tdc"), Err(failed));
        }
        // The node's latency was felt: commands arrived hundreds of µs after their state.
        let arrivals = trace(&rt)
            .values()
            .filter(|r| r["arrival_ns"].parse::<u64>().is_ok())
            .count();
        let check = if s["laws"]["tdc"]["status"] != "ok" {
            Err(format!("status {}: {s}", s["laws"]["tdc"]["status"]))
        } else if arrivals <= 700 {
            Err(format!("{arrivals} commands applied of 801"))
        } else {
            Ok(())
        };
        common::judge(common::disturbance(&s, "tdc"), check)?;
        common::assert_replays(&rt);
        Ok(())
    });
}

/// Commands deltaloop must refuse, each counted under its cause (other joint names, two efforts,
/// a NaN, the stamp of a tick gone, a second publisher), change nothing: between them the node's
/// answers give the built-in's run byte for byte (but for s and N̂).
#[test]
fn ros2_controller_refuses_and_counts_bad_commands() {
    let domain = 174;
    let tmp = tempfile::tempdir().unwrap();
    let builtin = tmp.path().join("builtin");
    common::run("configs/s1-ros2.toml", "lockstep", &builtin, &[]);
    let out = tmp.path().join("hostile");
    let hostile = "tests/peers/ros2_hostile.py";
    ok(
        &with_dds_controller(hostile, domain, "lockstep", &out, &[]),
        "the run",
    );
    let log = std::fs::read_to_string(out.join("tdc.controller.log")).unwrap();
    let why = "1 joint names, 1 lengths, 1 non-finite, 1 stale, 1 second publisher, 0 undecodable";
    assert!(
        log.contains(&format!("5 command(s) refused: {why}")),
        "{log}"
    );
    // The counts reach the run's record, as the plant's own refusals do.
    let summary = common::summary(&out);
    let m = &summary["laws"]["tdc"];
    assert_eq!(m["refused_replies"], 5, "{m}");
    assert_eq!(m["refused_replies_why"], why, "{m}");
    let report = std::fs::read_to_string(out.join("report.md")).unwrap();
    assert!(
        report.contains("the controller's transport refused 5 reply(ies)"),
        "{report}"
    );
    assert_eq!(robot_columns(&out), robot_columns(&builtin));
}

/// The run's node is in the ROS graph as `ros2 node list` finds it: `/deltaloop` on
/// `ros_discovery_info`, its publishers the run's topics with their ROS types.
#[test]
fn ros2_node_is_in_the_graph() {
    let tmp = tempfile::tempdir().unwrap();
    // The law's topics exist while the law runs: a run the host stalled into its safe stop
    // took them down before graph.py could see them, which says nothing about the graph;
    // such an attempt is run again (regression: it once failed the test).
    common::on_a_noisy_host("ros2_node_is_in_the_graph", |n| {
        let out = tmp.path().join(format!("run-{n}"));
        node_in_the_graph(&out)
    });
}

/// One attempt of [`ros2_node_is_in_the_graph`], the run's folder `out`.
fn node_in_the_graph(out: &Path) -> Result<(), String> {
    let domain = 173;
    // The hold keeps the run's node up while graph.py starts (seconds on a loaded host), and
    // graph.py waits for the law's topics (regression: it once read the graph before the law
    // had begun).
    let run = live_run(domain, "10", out).spawn().unwrap();
    wait_for(&out.join("config.toml"));
    let d = domain.to_string();
    let law = "/deltaloop/tdc/joint_states";
    let g = wait(
        node(
            "examples/ros2/graph.py",
            &["--domain", &d, "--wait-s", "30", "--expect", law],
        ),
        Duration::from_secs(60),
        "graph.py",
    );
    let run = wait(run, Duration::from_secs(60), "the run");
    if !run.status.success() {
        // A realtime run the host stalled past its budget ends in a safe stop, and its topics
        // with it: only a graph.py that found nothing while an undisturbed run ended badly
        // says something about the code.
        let failed = format!("the run failed ({}): {}", run.status, text(&run.stderr));
        match common::disturbance(&common::summary(out), "tdc") {
            None => panic!("undisturbed and still wrong: {failed}"),
            Some(why) if !g.status.success() => {
                let graph = format!("graph.py ({}): {}", g.status, text(&g.stderr));
                return Err(format!("{graph}; {failed} (disturbed: {why})"));
            }
            Some(_) => {}
        }
    }
    ok(&g, "graph.py");
    let graph: Value = serde_json::from_slice(&g.stdout).unwrap();
    let nodes = graph["nodes"].as_array().unwrap();
    let me = nodes
        .iter()
        .find(|n| n["name"] == "/deltaloop")
        .unwrap_or_else(|| panic!("no /deltaloop node in {graph}"));
    let publishes = |topic: &str, ty: &str| {
        me["publishers"]
            .as_array()
            .unwrap()
            .iter()
            .any(|p| p["topic"] == topic && p["type"] == ty)
    };
    for (topic, ty) in [
        ("/deltaloop/tdc/joint_states", "sensor_msgs/msg/JointState"),
        ("/deltaloop/tdc/reference", "sensor_msgs/msg/JointState"),
        (
            "/deltaloop/tdc/trajectory",
            "trajectory_msgs/msg/JointTrajectory",
        ),
        ("/tf", "tf2_msgs/msg/TFMessage"),
        ("/clock", "rosgraph_msgs/msg/Clock"),
        ("/diagnostics", "diagnostic_msgs/msg/DiagnosticArray"),
        ("/rosout", "rcl_interfaces/msg/Log"),
    ] {
        assert!(
            publishes(topic, ty),
            "/deltaloop does not publish {topic} ({ty}): {me}"
        );
    }
    assert_eq!(graph["unmatched_gids"], 0, "{graph}");
    Ok(())
}
