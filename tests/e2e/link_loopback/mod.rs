//! The link on one host, over loopback (no root needed): a sweep's `link_delay_us` axis runs
//! each point in realtime with the controller behind `deltaloop-bridge` (the far side with its own
//! iceoryx2 root), and its tracking matches the same delay injected in-process with
//! `transport_delay_us` = the measured median arrival; a run across the bridge measures the
//! link's round trip per tick (`link_rtt_ns`, `link_rtt.hlog`, `summary.json`, the report) and a
//! one-host run does not.

use crate::common;

use common::{deltaloop, summary};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::Duration;

mod far_process;
mod join;
mod refusals;
mod stall;
mod sweep;

/// One of these tests at a time: a realtime run shares two CPUs with the other.
static ONE_AT_A_TIME: std::sync::Mutex<()> = std::sync::Mutex::new(());

/// S1 with room for two "hosts" on this machine's two CPUs: a torque budget of 250 µs and 1000
/// misses in a row before the safe stop (as `tests/e2e/bridge_netns/`).
const BASE: &str = "name = \"link\"\n[scenario]\npath = \"s1\"\n[plant]\nfriction = true\n[controller]\npreset = \"matched\"\nlaws = [\"tdc\"]\n[loop]\ntorque_budget_us = 250\n[faults]\ncontroller_silence_ticks = 1000\n";

fn text(b: &[u8]) -> String {
    String::from_utf8_lossy(b).into_owned()
}

/// The rows of a CSV file as maps of column → cell.
fn rows(path: &Path) -> Vec<std::collections::HashMap<String, String>> {
    let mut rd = csv::Reader::from_path(path).unwrap();
    let h = rd.headers().unwrap().clone();
    rd.records()
        .map(|r| {
            let r = r.unwrap();
            h.iter()
                .zip(r.iter())
                .map(|(k, v)| (k.to_string(), v.to_string()))
                .collect()
        })
        .collect()
}

/// A free port of 127.0.0.1 (TCP; the near bridge binds UDP on it too).
fn free_port() -> u16 {
    let l = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    l.local_addr().unwrap().port()
}

/// A temp folder with S1 ([`BASE`]) and a fresh link key in it, and a free endpoint of
/// 127.0.0.1: (folder, config, key file, endpoint).
fn s1_with_key() -> (tempfile::TempDir, PathBuf, PathBuf, String) {
    let tmp = tempfile::tempdir().unwrap();
    let cfg = tmp.path().join("s1.toml");
    std::fs::write(&cfg, BASE).unwrap();
    let key = tmp.path().join("link.key");
    deltaloop_bridge::seal::LinkKey::write_new(&key).unwrap();
    let ep = format!("127.0.0.1:{}", free_port());
    (tmp, cfg, key, ep)
}

/// `deltaloop run CFG --mode lockstep --controller-remote EP --link-key KEY --out OUT`'s
/// arguments.
fn remote_lockstep<'a>(cfg: &'a Path, ep: &'a str, key: &'a Path, out: &'a Path) -> [&'a str; 10] {
    let s = |p: &'a Path| p.to_str().unwrap();
    [
        "run",
        s(cfg),
        "--mode",
        "lockstep",
        "--controller-remote",
        ep,
        "--link-key",
        s(key),
        "--out",
        s(out),
    ]
}

/// `deltaloop join EP --link-key KEY` with its own iceoryx2 root, output captured.
fn join_with(ep: &str, key: &Path, root: &Path) -> std::process::Child {
    Command::new(env!("CARGO_BIN_EXE_deltaloop"))
        .args(["join", ep, "--role", "controller", "--wait-s", "60"])
        .args(["--link-key", key.to_str().unwrap()])
        .env("DELTALOOP_IOX2_ROOT", root)
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap()
}

/// Waits for a run (120 s at most) and its `join` (30 s), then removes the far side's iceoryx2
/// root: their outputs.
fn finish_pair(
    run: std::process::Child,
    join: std::process::Child,
    far_root: &Path,
) -> (std::process::Output, std::process::Output) {
    let o = common::finish_within(run, Duration::from_secs(120), "deltaloop run");
    let j = common::finish_within(join, Duration::from_secs(30), "join");
    deltaloop_supervisor::ops::loopback::remove_root(far_root, false);
    (o, j)
}

/// `deltaloop join EP --role controller --link-key KEY --controller-cmd=CMD` with its own
/// iceoryx2 root, stderr captured.
fn join_with_cmd(ep: &str, key: &Path, root: &Path, cmd: &str) -> std::process::Child {
    Command::new(env!("CARGO_BIN_EXE_deltaloop"))
        .args(["join", ep, "--role", "controller", "--wait-s", "60"])
        .args(["--link-key", key.to_str().unwrap()])
        .arg(format!("--controller-cmd={cmd}"))
        .env("DELTALOOP_IOX2_ROOT", root)
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap()
}

/// `deltaloop join EP --role ROLE --link-key KEY` with its own iceoryx2 root, output captured.
fn join_as(ep: &str, role: &str, key: &Path, root: &Path) -> std::process::Child {
    Command::new(env!("CARGO_BIN_EXE_deltaloop"))
        .args(["join", ep, "--role", role, "--wait-s", "60"])
        .args(["--link-key", key.to_str().unwrap()])
        .env("DELTALOOP_IOX2_ROOT", root)
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap()
}
