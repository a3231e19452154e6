//! The ROS 2 face attacked and followed as its guide says: a node that starts before the run or
//! late, a node whose every command is refused, a DATA_FRAG that announces a huge sample, a
//! discovery flood. Every participant stays on loopback (deltaloop: this host only, its default;
//! Cyclone: interface `lo`, multicast off; the crafted datagrams go to 127.0.0.1), each test on a
//! domain of its own.

use crate::common;
use crate::ros2::{deltaloop, node, wait, wait_for};
use common::python::{root, text};
use std::net::UdpSocket;
use std::path::Path;
use std::process::{Child, Command, Output};
use std::time::{Duration, Instant};

fn all(o: &Output) -> String {
    format!("{}\n{}", text(&o.stdout), text(&o.stderr))
}

/// `run configs/s1-ros2.toml --mode lockstep --controller ros2 --out OUT` and `extra`.
fn robot_run(domain: u16, out: &Path, extra: &[&str]) -> Command {
    let mut c = deltaloop(
        domain,
        &[
            "run",
            "configs/s1-ros2.toml",
            "--mode",
            "lockstep",
            "--controller",
            "ros2",
            "--out",
            out.to_str().unwrap(),
        ],
    );
    c.args(extra);
    c
}

/// The example node on `domain` with `config`.
fn example_node(domain: u16, config: &Path) -> Child {
    let d = domain.to_string();
    let c = config.to_str().unwrap();
    let args = ["--config", c, "--domain", &d, "--idle-s", "2"];
    node("examples/ros2/controller.py", &args)
}

/// The guide's two ways to start the example node both close the loop: before the run (with an
/// earlier run's resolved config, as the guide says) and seconds after it. The robot waits for
/// the node's reader and writer before tick 0 and says on the terminal what it waits for,
/// rather than faulting on a tick 0 its node never saw.
#[test]
fn regression_a_node_started_first_or_late_is_waited_for() {
    let domain = 176;
    let tmp = tempfile::tempdir().unwrap();

    // Late: 1.5 s after the run, which says what it waits for meanwhile.
    let late = tmp.path().join("late");
    let run = robot_run(domain, &late, &[]).spawn().unwrap();
    wait_for(&late.join("config.toml"));
    std::thread::sleep(Duration::from_millis(1500));
    let ctl = example_node(domain, &late.join("config.toml"));
    let run = wait(run, Duration::from_secs(120), "the run with the node late");
    let ctl = wait(ctl, Duration::from_secs(60), "the node started late");
    assert!(ctl.status.success(), "{}", all(&ctl));
    assert!(run.status.success(), "{}", all(&run));
    let said = text(&run.stderr);
    assert!(
        said.contains(
            "waiting up to 20 s for a ROS 2 node that reads /robot_joint_states and writes /robot_joint_commands (domain 176, this host only)"
        ),
        "{said}"
    );
    assert_eq!(common::summary(&late)["laws"]["tdc"]["status"], "ok");

    // First, with that run's config: the node waits for the trajectory, the run comes later.
    let ctl = example_node(domain, &late.join("config.toml"));
    std::thread::sleep(Duration::from_secs(1));
    let first = tmp.path().join("first");
    let run = wait(
        robot_run(domain, &first, &[]).spawn().unwrap(),
        Duration::from_secs(120),
        "the run with the node first",
    );
    let ctl = wait(ctl, Duration::from_secs(60), "the node started first");
    assert!(ctl.status.success(), "{}", all(&ctl));
    assert!(run.status.success(), "{}", all(&run));
    let s = common::summary(&first);
    assert_eq!(s["laws"]["tdc"]["status"], "ok", "{s}");
}

/// A node whose every command is refused (stale stamps), in realtime: the terminal line of the
/// fault names the refusal, not only the silence, and summary.json keeps the count though the run
/// faulted (the robot gives up when the plant does, 500 ticks here, not 2 s later when the
/// supervisor has stopped it).
#[test]
fn regression_refused_commands_are_named_and_counted_when_the_run_faults() {
    let domain = 177;
    let tmp = tempfile::tempdir().unwrap();
    let cfg = tmp.path().join("stale.toml");
    let base = std::fs::read_to_string(root().join("configs/s1-ros2.toml")).unwrap();
    let within = format!("{base}\n[faults]\ncontroller_silence_ticks = 500\n");
    std::fs::write(&cfg, within).unwrap();
    let out = tmp.path().join("run");
    let c = cfg.to_str().unwrap();
    let o = out.to_str().unwrap();
    let args = ["run", c, "--controller", "ros2", "--out", o];
    let run = deltaloop(domain, &args).spawn().unwrap();
    wait_for(&out.join("config.toml"));
    let d = domain.to_string();
    let conf = out.join("config.toml");
    let args = [
        "--config",
        conf.to_str().unwrap(),
        "--domain",
        &d,
        "--stale",
    ];
    let peer = node("tests/peers/ros2_hostile.py", &args);
    let run = wait(run, Duration::from_secs(120), "the run");
    let peer = wait(peer, Duration::from_secs(60), "the stale node");
    let said = format!("{}\nthe node: {}", all(&run), all(&peer));
    assert!(!run.status.success(), "{said}");
    assert!(
        said.contains("the ROS 2 node did not answer tick 0 within 500 ms: its 1 command(s) meanwhile were refused, the first: stale, stamped 0 s 1000000 ns (tick 0 is at 0 ns)"),
        "{said}"
    );
    let s = common::summary(&out);
    let m = &s["laws"]["tdc"];
    assert_eq!(m["refused_replies"], 1, "{s}");
    assert_eq!(
        m["refused_replies_why"],
        "0 joint names, 0 lengths, 0 non-finite, 1 stale, 0 second publisher, 0 undecodable",
        "{s}"
    );
}

/// An RTPS message from a participant `prefix` carrying one submessage `sub`.
fn rtps(prefix: [u8; 12], sub: &[u8]) -> Vec<u8> {
    let mut m = b"RTPS\x02\x04\x01\x0f".to_vec();
    m.extend_from_slice(&prefix);
    m.extend_from_slice(sub);
    m
}

/// SPDP's built-in writer and reader.
const SPDP_WRITER: [u8; 4] = [0, 1, 0, 0xc2];
const SPDP_READER: [u8; 4] = [0, 1, 0, 0xc7];

/// A DATA_FRAG to the SPDP reader: fragment 1 (of `frag` bytes) of a sample that announces
/// `sample_size` bytes.
fn data_frag(sample_size: u32, frag: u16) -> Vec<u8> {
    let mut b = Vec::new();
    b.extend_from_slice(&0u16.to_le_bytes()); // extraFlags
    b.extend_from_slice(&28u16.to_le_bytes()); // octetsToInlineQos
    b.extend_from_slice(&SPDP_READER);
    b.extend_from_slice(&SPDP_WRITER);
    b.extend_from_slice(&0i32.to_le_bytes()); // writerSN high
    b.extend_from_slice(&1u32.to_le_bytes()); // writerSN low
    b.extend_from_slice(&1u32.to_le_bytes()); // fragmentStartingNum
    b.extend_from_slice(&1u16.to_le_bytes()); // fragmentsInSubmessage
    b.extend_from_slice(&frag.to_le_bytes()); // fragmentSize
    b.extend_from_slice(&sample_size.to_le_bytes());
    b.extend(std::iter::repeat_n(0u8, usize::from(frag)));
    let mut sub = vec![0x16, 0x01];
    sub.extend_from_slice(&(b.len() as u16).to_le_bytes());
    sub.extend(b);
    sub
}

/// RTPS's unicast ports on `domain` (metatraffic and user) of participants 0..8: where a
/// localhost-only participant listens.
fn unicast_ports(domain: u16) -> Vec<u16> {
    (0..8u16)
        .flat_map(|p| {
            let meta = 7400 + 250 * domain + 10 + 2 * p;
            [meta, meta + 1]
        })
        .collect()
}

/// A process's peak resident memory (VmHWM), KiB.
fn peak_kib(pid: u32) -> u64 {
    let s = std::fs::read_to_string(format!("/proc/{pid}/status")).unwrap();
    let l = s.lines().find(|l| l.starts_with("VmHWM:")).unwrap();
    l.split_whitespace().nth(1).unwrap().parse().unwrap()
}

/// One DATA_FRAG announcing a 256 MiB sample, to every unicast port of the run's domain on
/// loopback: the supervisor (whose participant serves `--ros2`) allocates no more than 16 MiB
/// for it, and the run completes (lockstep: a loaded host does not fault it).
#[test]
fn regression_an_announced_sample_size_allocates_nothing_before_its_fragments() {
    let domain = 178;
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("run");
    let args = [
        "run",
        "configs/s1-nominal.toml",
        "--law",
        "tdc",
        "--mode",
        "lockstep",
        "--hold-s",
        "20",
        "--ros2",
        "--out",
        out.to_str().unwrap(),
    ];
    let run = deltaloop(domain, &args).spawn().unwrap();
    // The trace part appears at tick 0; 20 s of hold keep the loop running (≈ 3 s of lockstep
    // in a debug build) past both readings of its peak memory.
    // Once the loop runs: the run's own tables are allocated before START.
    wait_for(&out.join("trace.tdc.part"));
    std::thread::sleep(Duration::from_millis(300));
    let before = peak_kib(run.id());
    let sock = UdpSocket::bind("127.0.0.1:0").unwrap();
    let msg = rtps([0x5a; 12], &data_frag(256 << 20, 1024));
    for port in unicast_ports(domain) {
        let _ = sock.send_to(&msg, ("127.0.0.1", port));
    }
    std::thread::sleep(Duration::from_millis(800));
    let after = peak_kib(run.id());
    let run = wait(run, Duration::from_secs(60), "the run");
    assert!(
        after.saturating_sub(before) <= 16 << 10,
        "peak RSS {before} KiB → {after} KiB"
    );
    assert!(run.status.success(), "{}", all(&run));
    assert_eq!(common::summary(&out)["laws"]["tdc"]["status"], "ok");
}

/// A participant announcement (SPDP DATA, PL_CDR) of participant `prefix`: its GUID, a
/// metatraffic and default unicast locator on 127.0.0.1:`port`, a lease of 300 s.
fn spdp_data(prefix: [u8; 12], port: u16) -> Vec<u8> {
    fn param(b: &mut Vec<u8>, id: u16, v: &[u8]) {
        b.extend_from_slice(&id.to_le_bytes());
        b.extend_from_slice(&(v.len() as u16).to_le_bytes());
        b.extend_from_slice(v);
    }
    let mut locator = 1i32.to_le_bytes().to_vec(); // UDPv4
    locator.extend_from_slice(&u32::from(port).to_le_bytes());
    locator.extend_from_slice(&[0; 12]);
    locator.extend_from_slice(&[127, 0, 0, 1]);
    let mut guid = prefix.to_vec();
    guid.extend_from_slice(&[0, 0, 1, 0xc1]);
    let mut pl = vec![0x00, 0x03, 0, 0]; // PL_CDR_LE
    param(&mut pl, 0x0015, &[2, 4, 0, 0]); // protocol version
    param(&mut pl, 0x0016, &[0x01, 0x0f, 0, 0]); // vendor
    param(&mut pl, 0x0050, &guid); // participant GUID
    param(&mut pl, 0x0032, &locator); // metatraffic unicast
    param(&mut pl, 0x0031, &locator); // default unicast
    param(&mut pl, 0x0058, &0x3fu32.to_le_bytes()); // built-in endpoints
    let mut lease = 300i32.to_le_bytes().to_vec();
    lease.extend_from_slice(&0u32.to_le_bytes());
    param(&mut pl, 0x0002, &lease); // lease duration
    param(&mut pl, 0x0001, &[]); // sentinel
    let mut b = Vec::new();
    b.extend_from_slice(&0u16.to_le_bytes()); // extraFlags
    b.extend_from_slice(&16u16.to_le_bytes()); // octetsToInlineQos
    b.extend_from_slice(&SPDP_READER);
    b.extend_from_slice(&SPDP_WRITER);
    b.extend_from_slice(&0i32.to_le_bytes());
    b.extend_from_slice(&1u32.to_le_bytes());
    b.extend(pl);
    let mut sub = vec![0x15, 0x05]; // DATA, little endian, data present
    sub.extend_from_slice(&(b.len() as u16).to_le_bytes());
    sub.extend(b);
    rtps(prefix, &sub)
}

/// 30,000 fake participants announced to a `run --ros2`: the run exits within 2 s of writing
/// summary.json whatever discovery holds. Ignored (a flood); its command is in
/// docs/guide/failure-behaviour.md.
#[test]
#[ignore = "a discovery flood: cargo test --test e2e ros2_face::regression_a_discovery_flood -- --ignored"]
fn regression_a_discovery_flood_does_not_hold_the_exit() {
    let domain = 179;
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("run");
    let args = [
        "run",
        "configs/s1-nominal.toml",
        "--law",
        "tdc",
        "--mode",
        "realtime",
        "--hold-s",
        "3",
        "--ros2",
        "--out",
        out.to_str().unwrap(),
    ];
    let mut run = deltaloop(domain, &args).spawn().unwrap();
    wait_for(&out.join("config.toml"));
    let sock = UdpSocket::bind("127.0.0.1:0").unwrap();
    let sink = sock.local_addr().unwrap().port();
    let ports = unicast_ports(domain);
    for i in 0..30_000u32 {
        let mut prefix = [0x77; 12];
        prefix[..4].copy_from_slice(&i.to_le_bytes());
        let m = spdp_data(prefix, sink);
        for p in ports.iter().step_by(2) {
            let _ = sock.send_to(&m, ("127.0.0.1", *p));
        }
        if i % 500 == 0 {
            std::thread::sleep(Duration::from_millis(5));
        }
    }
    // The announcements were taken: the run answers new participants at their locator.
    sock.set_read_timeout(Some(Duration::from_secs(5))).unwrap();
    let mut buf = [0u8; 1500];
    let heard = sock
        .recv(&mut buf)
        .is_ok_and(|n| buf[..n].starts_with(b"RTPS"));
    assert!(heard, "the run never answered a fake participant");
    let summary = out.join("summary.json");
    wait_for(&summary);
    let written = Instant::now();
    let status = loop {
        if let Some(s) = run.try_wait().unwrap() {
            break s;
        }
        if written.elapsed() > Duration::from_secs(30) {
            let _ = run.kill();
            break run.wait().unwrap();
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    let exited = written.elapsed();
    let said = all(&run.wait_with_output().unwrap());
    assert!(
        exited <= Duration::from_secs(2),
        "the run exited {exited:?} after summary.json ({status}): {said}"
    );
    assert!(status.success(), "{status}");
}
