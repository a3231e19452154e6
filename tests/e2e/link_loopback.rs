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

/// One of these tests at a time: a realtime run shares two CPUs with the other.
static ONE_AT_A_TIME: std::sync::Mutex<()> = std::sync::Mutex::new(());

/// S1 with room for two "hosts" on this machine's two CPUs: a torque budget of 250 µs and 1000
/// misses in a row before the safe stop (as `tests/e2e/bridge_netns.rs`).
const BASE: &str = "name = \"link\"\n[scenario]\npath = \"s1\"\n[plant]\nfriction = true\n[controller]\npreset = \"matched\"\nlaws = [\"tdc\"]\n[loop]\ntorque_budget_us = 250\n[faults]\ncontroller_silence_ticks = 1000\n";

const SWEEP: &str = "name = \"link\"\nbase = \"base.toml\"\nscenarios = [\"s1\"]\npresets = [\"matched\"]\nlaws = [\"tdc\"]\ntde_delay_samples = [1]\ntransport_delay_samples = [0]\nlink_delay_us = [0, 25]\nsensitivity = false\n";

/// The tolerance the report states (`LINK_MATCH_TOLERANCE`).
const TOLERANCE: f64 = deltaloop_supervisor::ops::sweep::LINK_MATCH_TOLERANCE;

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

/// Nothing of the far sides of sweep `pid` is left: no root folder under `tmp` (the sweep's
/// TMPDIR), no shared memory under such a root's prefix, no process with such a root.
fn assert_no_far_roots(tmp: &Path, pid: u32) {
    let left: Vec<String> = std::fs::read_dir(tmp)
        .unwrap()
        .flatten()
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| n.starts_with("deltaloop-link-"))
        .collect();
    assert!(left.is_empty(), "far roots left behind: {left:?}");
    let roots: Vec<String> = (0..8)
        .map(|n| format!("{}/deltaloop-link-{pid}-{n}", tmp.display()))
        .collect();
    let prefixes: Vec<String> = roots
        .iter()
        .filter_map(|r| deltaloop_transport::ipc::root_of(r).map(|(_, p)| p))
        .collect();
    let shm: Vec<String> = std::fs::read_dir("/dev/shm")
        .unwrap()
        .flatten()
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| prefixes.iter().any(|p| n.starts_with(p.as_str())))
        .collect();
    assert!(shm.is_empty(), "far shared memory left behind: {shm:?}");
    let procs: Vec<String> = std::fs::read_dir("/proc")
        .unwrap()
        .flatten()
        .filter(|e| {
            std::fs::read(e.path().join("environ")).is_ok_and(|env| {
                String::from_utf8_lossy(&env)
                    .contains(&format!("{}/deltaloop-link-", tmp.display()))
            })
        })
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .collect();
    assert!(procs.is_empty(), "far processes left behind: {procs:?}");
}

/// A folder with the link sweep ([`SWEEP`] over [`BASE`]) and a TMPDIR for its far roots.
fn link_sweep() -> (tempfile::TempDir, PathBuf, PathBuf) {
    let tmp = tempfile::tempdir().unwrap();
    std::fs::write(tmp.path().join("base.toml"), BASE).unwrap();
    let sweep = tmp.path().join("sweep.toml");
    std::fs::write(&sweep, SWEEP).unwrap();
    let far_tmp = tmp.path().join("tmp");
    std::fs::create_dir_all(&far_tmp).unwrap();
    (tmp, sweep, far_tmp)
}

/// `deltaloop sweep SWEEP --out OUT` with TMPDIR = `tmp` (where the far roots go).
fn sweep_cmd(sweep: &Path, out: &Path, tmp: &Path) -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_deltaloop"));
    c.args(["sweep", sweep.to_str().unwrap(), "--out"])
        .arg(out)
        .env("TMPDIR", tmp)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped());
    c
}

/// What a link row says: Ok(difference) for a run that matched its twin, or an undisturbed one
/// (matched or not), Err(why) for a mismatch the machine disturbed (which says nothing).
/// Anything else is a failure: a run that ended badly without the machine having disturbed it,
/// or an ok run without its injected twin.
fn verdict(r: &std::collections::HashMap<String, String>) -> Result<f64, String> {
    let f = |k: &str| r[k].parse::<f64>().ok();
    let d = &r["link_delay_us"];
    let disturbed = &r["link_disturbed"];
    if r["status"] != "ok" {
        assert!(
            !disturbed.is_empty(),
            "link {d} µs: {} ({}) and the machine did not disturb it: {r:?}",
            r["status"],
            r["reason"]
        );
        return Err(format!("link {d} µs: {} ({})", r["status"], r["reason"]));
    }
    let (Some(rms), Some(inj)) = (f("rms_rad"), f("injected_rms_rad")) else {
        panic!("link {d} µs: an ok run without its injected twin: {r:?}");
    };
    let diff = rms / inj - 1.0;
    eprintln!(
        "link {d} µs: link rtt p50 {} µs, median arrival {} µs, misses {}, RMS {rms:.4e} realtime vs {inj:.4e} injected ({:+.2} %) {}",
        r["link_rtt_p50_us"],
        r["median_arrival_us"],
        r["deadline_misses"],
        diff * 100.0,
        r["link_disturbed"]
    );
    // A match is a match, disturbed or not: what the machine does to a run can move it away
    // from its twin, not onto it (a plant stall of 0.4 ms with `stretch` pauses simulated time
    // and leaves the robot as it was). Only a mismatch needs an undisturbed run to count.
    if diff.abs() <= TOLERANCE {
        return Ok(diff);
    }
    if !disturbed.is_empty() {
        return Err(format!("link {d} µs: disturbed: {disturbed}"));
    }
    // A few scattered misses leave the run a fair twin for the sweep's verdict, but a constant
    // delay does not model them: at a sensitive moment of the motion they move the RMS by more
    // than the tolerance (seen: 11 % in a clean clone's CI). Only a run without a miss must match.
    let misses = f("deadline_misses").unwrap_or(0.0);
    if misses > 0.0 {
        return Err(format!(
            "link {d} µs: {misses} miss(es), {:+.2} %: not matched, not conclusive",
            diff * 100.0
        ));
    }
    Ok(diff)
}

/// A link-delay sweep: each point in realtime across the loopback bridge, next to the same delay
/// injected in-process at its median arrival; each point must match its twin within the
/// tolerance in one of at most three sweeps (`common::on_a_noisy_host`). What every sweep must
/// do whatever the host does is asserted on each: it ends, writes both link points in realtime
/// with their round-trip logs and the report's section, and leaves no far side behind. A run the
/// loaded machine disturbed (a fault, too many misses or a burst of them, a stalled plant: the
/// sweep's `link_disturbed`, the runs' own classifier) counts when it matched and says nothing
/// when it did not; an undisturbed one may still miss the tolerance now and then (a few misses
/// at a sensitive moment of the motion: docs/guide/delay-study.md), so the test fails when a
/// point had undisturbed runs and none matched in three sweeps; a point the machine disturbed in
/// all three is inconclusive.
#[test]
fn link_delay_sweep_matches_the_injected_delay() {
    let test = "link_delay_sweep_matches_the_injected_delay";
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let (tmp, sweep, far_tmp) = link_sweep();
    let mut matched = std::collections::BTreeMap::<String, f64>::new();
    let mut missed = std::collections::BTreeMap::<String, Vec<String>>::new();
    // The largest growth of the median arrival from 0 to 25 µs each way within one sweep.
    let mut grew = f64::NEG_INFINITY;
    common::on_a_noisy_host(test, |attempt| {
        let out = tmp.path().join(format!("out{attempt}"));
        let child = sweep_cmd(&sweep, &out, &far_tmp).spawn().unwrap();
        let pid = child.id();
        let o = common::finish_within(child, Duration::from_secs(120), "the link sweep");
        assert!(o.status.success(), "{}", text(&o.stderr));
        assert_no_far_roots(&far_tmp, pid);
        let all = rows(&out.join("sweep.csv"));
        let link: Vec<_> = all
            .iter()
            .filter(|r| !r["link_delay_us"].is_empty())
            .collect();
        assert_eq!(link.len(), 2, "{all:?}");
        for r in &link {
            assert_eq!(r["mode"], "realtime");
            let folder = out.join("points").join(format!(
                "s1-matched-tdc-l1-d0-u0-c0-link{}",
                (r["link_delay_us"].parse::<f64>().unwrap() * 1e3).round()
            ));
            assert!(folder.join("tdc.link_rtt.hlog").is_file(), "{folder:?}");
            let cfg = std::fs::read_to_string(folder.join("config.toml")).unwrap();
            assert!(
                cfg.contains("deltaloop-bridge") && cfg.contains("127.0.0.1:"),
                "{cfg}"
            );
            // The replay-based verdict is filled for every point that ran to its end, disturbed
            // or not (the replay is deterministic), and replays the point's own trace.
            if r["status"] == "ok" {
                let replay: f64 = r["replay_rms_rad"].parse().unwrap_or(f64::NAN);
                assert!(replay.is_finite() && replay > 0.0, "{r:?}");
                assert!(folder.join("replay/trace.csv").is_file(), "{folder:?}");
            }
        }
        let report_text = std::fs::read_to_string(out.join("report.md")).unwrap();
        assert!(
            report_text.contains("| a constant delay explains it |"),
            "{report_text}"
        );
        let report = std::fs::read_to_string(out.join("report.md")).unwrap();
        assert!(
            report.contains("## Emulated network delay (realtime, across the bridge)"),
            "{report}"
        );
        // The delay is in the data: about 2·25 µs more arrival at 25 µs than at 0 µs, in the
        // same sweep (the machine's load moves both alike).
        let arrival = |d: f64| {
            link.iter()
                .find(|r| r["link_delay_us"].parse::<f64>().ok() == Some(d))
                .and_then(|r| r["median_arrival_us"].parse::<f64>().ok())
        };
        if let (Some(a0), Some(a25)) = (arrival(0.0), arrival(25.0)) {
            grew = grew.max(a25 - a0);
        }
        let mut why = Vec::new();
        for r in &link {
            match verdict(r) {
                Ok(diff) if diff.abs() > TOLERANCE => {
                    let w = format!(
                        "link {} µs, undisturbed: RMS realtime {} vs injected {}: {:+.2} %, beyond ±{} %",
                        r["link_delay_us"],
                        r["rms_rad"],
                        r["injected_rms_rad"],
                        diff * 100.0,
                        TOLERANCE * 100.0
                    );
                    missed
                        .entry(r["link_delay_us"].clone())
                        .or_default()
                        .push(w.clone());
                    why.push(w);
                }
                Ok(_) => {
                    matched.insert(
                        r["link_delay_us"].clone(),
                        r["median_arrival_us"].parse().unwrap(),
                    );
                }
                Err(w) => why.push(w),
            }
        }
        if matched.len() == 2 && grew > 25.0 {
            return Ok(());
        }
        if attempt == common::ATTEMPTS {
            // The last sweep: what no disturbance excuses fails the test.
            // Only a sweep none of whose points the machine disturbed must show the growth.
            assert!(
                grew > 25.0 || !why.is_empty(),
                "the median arrival grew by {grew} µs at most from 0 to 25 µs each way in one sweep (2·25 expected)"
            );
            missed.retain(|d, _| !matched.contains_key(d));
            assert!(
                missed.is_empty(),
                "undisturbed runs that never matched in three sweeps: {missed:?}"
            );
        }
        Err(format!(
            "the match of {} point(s) is not checked: {why:?} (matched: {matched:?})",
            2 - matched.len()
        ))
    });
}

/// A lockstep run across the loopback bridge (deterministic, so no retry) fills `link_rtt_ns`
/// on every answered tick and writes `link_rtt.hlog`, the summary's `link_rtt` and the report's
/// row; the same run on one host leaves the column empty and writes none of them.
#[test]
fn link_round_trip_is_measured_across_the_bridge_only() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let tmp = tempfile::tempdir().unwrap();
    let cfg = tmp.path().join("s1.toml");
    std::fs::write(&cfg, BASE).unwrap();
    let port = {
        let l = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
        l.local_addr().unwrap().port()
    };
    let ep = format!("127.0.0.1:{port}");
    let far_root = tmp.path().join("far-root");
    let key = tmp.path().join("link.key");
    deltaloop_bridge::seal::LinkKey::write_new(&key).unwrap();
    let join = join_with(&ep, &key, &far_root);
    let remote = tmp.path().join("remote");
    let o = deltaloop(&remote_lockstep(&cfg, &ep, &key, &remote));
    let j = common::finish_within(join, Duration::from_secs(30), "deltaloop join");
    // The far root's shared memory (iceoryx2's management segment stays behind otherwise).
    deltaloop_supervisor::ops::loopback::remove_root(&far_root, false);
    assert!(o.status.success(), "{}", text(&o.stderr));
    assert!(j.status.success(), "join: {}", text(&j.stderr));
    let local = tmp.path().join("local");
    common::run(cfg.to_str().unwrap(), "lockstep", &local, &[]);

    let r = rows(&remote.join("tdc.timing.csv"));
    let filled: Vec<u64> = r
        .iter()
        .filter_map(|r| r["link_rtt_ns"].parse().ok())
        .collect();
    assert!(
        filled.len() + 5 > r.len(),
        "{} of {}",
        filled.len(),
        r.len()
    );
    // Each is the round trip less the far residence: positive, and below the round trip.
    for row in r.iter().filter(|r| !r["link_rtt_ns"].is_empty()).take(100) {
        let n = |k: &str| row[k].parse::<u64>().unwrap();
        let rtt = n("torque_rx_ns") - n("state_pub_ns");
        let residence = n("ctrl_pub_ns") - n("ctrl_rx_ns");
        assert_eq!(n("link_rtt_ns"), rtt - residence, "{row:?}");
    }
    let s = summary(&remote);
    let link = &s["timing"]["tdc"]["link_rtt"];
    assert!(link["p50_us"].as_f64().unwrap() > 1.0, "{link}");
    assert!(remote.join("tdc.link_rtt.hlog").is_file());
    assert!(remote.join("tdc.link_rtt.hgrm").is_file());
    let report = std::fs::read_to_string(remote.join("report.md")).unwrap();
    assert!(report.contains("| `tdc` | link round trip |"), "{report}");

    let r = rows(&local.join("tdc.timing.csv"));
    assert!(r.iter().all(|r| r["link_rtt_ns"].is_empty()));
    let s = summary(&local);
    assert!(s["timing"]["tdc"].get("link_rtt").is_none(), "{s}");
    assert!(!local.join("tdc.link_rtt.hlog").exists());
    let report = std::fs::read_to_string(local.join("report.md")).unwrap();
    assert!(!report.contains("link round trip"), "{report}");
}

/// Ctrl-C (SIGINT) during a link point: the sweep exits 130 and leaves no far bridge, root or
/// shared memory behind.
#[test]
fn an_interrupted_link_sweep_leaves_nothing_behind() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let (tmp, sweep, far_tmp) = link_sweep();
    let out = tmp.path().join("out");
    let child = sweep_cmd(&sweep, &out, &far_tmp).spawn().unwrap();
    let pid = child.id();
    // The first link point's far bridge is up once its log exists; then the run is under way.
    let log = out.join("points/s1-matched-tdc-l1-d0-u0-c0-link0/far.log");
    let t0 = std::time::Instant::now();
    while !log.is_file() && t0.elapsed() < Duration::from_secs(60) {
        std::thread::sleep(Duration::from_millis(20));
    }
    assert!(log.is_file(), "no link point started within 60 s ({log:?})");
    std::thread::sleep(Duration::from_millis(400));
    // SAFETY: our own child, not yet reaped.
    unsafe { libc::kill(pid as i32, libc::SIGINT) };
    let o = common::finish_within(child, Duration::from_secs(30), "the interrupted link sweep");
    eprintln!("{}", text(&o.stderr));
    assert_eq!(o.status.code(), Some(130), "{}", text(&o.stderr));
    assert_no_far_roots(&far_tmp, pid);
}

/// A free port of 127.0.0.1 (TCP; the near bridge binds UDP on it too).
fn free_port() -> u16 {
    let l = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    l.local_addr().unwrap().port()
}

/// A connection to `ep` once something listens there (the near bridge, after set-up).
fn connect_when_listening(ep: &str) -> std::net::TcpStream {
    let t0 = std::time::Instant::now();
    loop {
        if let Ok(s) = std::net::TcpStream::connect(ep) {
            return s;
        }
        assert!(
            t0.elapsed() < Duration::from_secs(30),
            "nothing listens at {ep}"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// Everything a connection receives until the other side closes it (or 8 s pass).
fn all_it_hears(mut s: std::net::TcpStream) -> Vec<u8> {
    use std::io::Read;
    s.set_read_timeout(Some(Duration::from_secs(8))).unwrap();
    let mut got = Vec::new();
    let _ = s.read_to_end(&mut got);
    got
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

/// The link's mutual authentication, from the outside: a stranger who connects first to a
/// waiting `run --controller-remote --link-key` (and one who connects and stays silent) learns
/// nothing of the run and cannot be its controller; a `join` with another key is refused in one
/// line on both sides within seconds; the honest `join` that comes after them completes the run,
/// its trace byte-identical to in-process, and the run records whom it refused.
#[test]
fn strangers_and_wrong_keys_are_refused_and_the_honest_join_runs_byte_identical() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let (tmp, cfg, key, ep) = s1_with_key();
    let other = tmp.path().join("other.key");
    deltaloop_bridge::seal::LinkKey::write_new(&other).unwrap();
    let remote = tmp.path().join("remote");
    let run = common::spawn(&remote_lockstep(&cfg, &ep, &key, &remote));
    // A stranger first: a handshake-shaped message of junk. Then one that says nothing at all
    // and holds its connection while the others come.
    let mut stranger = connect_when_listening(&ep);
    let silent = connect_when_listening(&ep);
    std::io::Write::write_all(
        &mut stranger,
        &[&48u16.to_le_bytes()[..], &[7u8; 48]].concat(),
    )
    .unwrap();
    let heard = all_it_hears(stranger);
    assert!(
        heard.is_empty(),
        "the stranger was told {} bytes",
        heard.len()
    );
    // A join with another key: the near side says it refused the key, and the join names the
    // key at once (it does not take the refusal for a busy near side and wait out --wait-s).
    let t0 = std::time::Instant::now();
    let wrong = Command::new(env!("CARGO_BIN_EXE_deltaloop"))
        .args(["join", &ep, "--role", "controller", "--wait-s", "60"])
        .args(["--link-key", other.to_str().unwrap()])
        .env("DELTALOOP_IOX2_ROOT", tmp.path().join("root-wrong"))
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let w = common::finish_within(wrong, Duration::from_secs(30), "join with another key");
    assert!(t0.elapsed() < Duration::from_secs(10), "{:?}", t0.elapsed());
    assert_eq!(w.status.code(), Some(3));
    let said = text(&w.stderr);
    assert!(
        said.contains("does not hold this link key") && !said.contains("trying again"),
        "{said}"
    );
    // The honest side, last: the run completes as if the others had never been there.
    let far_root = tmp.path().join("far-root");
    let honest = join_with(&ep, &key, &far_root);
    let o = common::finish_within(run, Duration::from_secs(120), "deltaloop run");
    let j = common::finish_within(honest, Duration::from_secs(30), "honest join");
    drop(silent);
    deltaloop_supervisor::ops::loopback::remove_root(&far_root, false);
    assert!(o.status.success(), "{}", text(&o.stderr));
    assert!(j.status.success(), "join: {}", text(&j.stderr));
    let local = tmp.path().join("local");
    common::run(cfg.to_str().unwrap(), "inproc", &local, &[]);
    assert!(
        std::fs::read(remote.join("trace.csv")).unwrap()
            == std::fs::read(local.join("trace.csv")).unwrap(),
        "trace.csv across the sealed link differs from inproc"
    );
    let s = summary(&remote);
    // The built-in controller on the far host, not a foreign one (nor the near bridge).
    assert!(s.get("controller_label").is_none(), "{s}");
    let sec = &s["timing"]["tdc"]["link_security"];
    let fp = deltaloop_bridge::seal::LinkKey::read(&key)
        .unwrap()
        .fingerprint();
    assert_eq!(sec["key_fingerprint"], fp.as_str(), "{sec}");
    assert!(
        sec["peer"].as_str().unwrap().starts_with("127.0.0.1:"),
        "{sec}"
    );
    // The stranger and the wrong key at least (the silent one, if its 2 s ran out first).
    assert!(sec["refused_connections"].as_u64().unwrap() >= 2, "{sec}");
    assert_eq!(sec["refused_datagrams"]["forged"], 0, "{sec}");
    let log = std::fs::read_to_string(remote.join("tdc.controller.log")).unwrap();
    assert!(log.contains("failed authentication"), "{log}");
    let report = std::fs::read_to_string(remote.join("report.md")).unwrap();
    assert!(
        report.contains(&format!("joined with link key {fp}")),
        "{report}"
    );
    assert!(
        !report.contains(
            &deltaloop_bridge::seal::LinkKey::read(&key)
                .unwrap()
                .to_hex()
        )
    );
    assert!(
        !text(&o.stderr).contains(
            &deltaloop_bridge::seal::LinkKey::read(&key)
                .unwrap()
                .to_hex()
        )
    );
}

/// A `join --runs N` waiting at a listener of this test (the near side), with its own root.
fn join_runs(port: u16, key: &Path, runs: u32, root: &Path) -> std::process::Child {
    Command::new(env!("CARGO_BIN_EXE_deltaloop"))
        .args(["join", &format!("127.0.0.1:{port}"), "--role", "controller"])
        .args(["--runs", &runs.to_string(), "--wait-s", "60"])
        .args(["--link-key", key.to_str().unwrap()])
        .env("DELTALOOP_IOX2_ROOT", root)
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap()
}

/// The next connection to `l`, within 30 s.
fn accept_within(l: &std::net::TcpListener) -> std::net::TcpStream {
    l.set_nonblocking(true).unwrap();
    let t0 = std::time::Instant::now();
    loop {
        match l.accept() {
            Ok((s, _)) => {
                s.set_nonblocking(false).unwrap();
                return s;
            }
            Err(_) if t0.elapsed() < Duration::from_secs(30) => {
                std::thread::sleep(Duration::from_millis(10))
            }
            Err(e) => panic!("nobody connected within 30 s: {e}"),
        }
    }
}

/// SIGTERM to `child`, then its output within 5 s and how long that took.
fn terminate(child: std::process::Child) -> (std::process::Output, Duration) {
    let t0 = std::time::Instant::now();
    // SAFETY: our own child, not yet reaped.
    unsafe { libc::kill(child.id() as i32, libc::SIGTERM) };
    let o = common::finish_within(child, Duration::from_secs(10), "deltaloop join");
    (o, t0.elapsed())
}

/// Regression: a `join` whose near side authenticated and then said nothing ignored SIGINT and
/// SIGTERM for 28 s; it now stops at once, exit 5, saying what it was waiting for.
#[test]
fn regression_join_stops_on_sigterm_while_the_near_side_is_silent() {
    let tmp = tempfile::tempdir().unwrap();
    let key = tmp.path().join("link.key");
    let k = deltaloop_bridge::seal::LinkKey::write_new(&key).unwrap();
    let l = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let port = l.local_addr().unwrap().port();
    let root = tmp.path().join("far-root");
    let join = join_runs(port, &key, 1, &root);
    let mut s = accept_within(&l);
    let session = deltaloop_bridge::seal::Session::generate().unwrap();
    deltaloop_bridge::seal::respond(&mut s, &k, &session, Duration::from_secs(10)).unwrap();
    // Authenticated, and then no HELLO: the join waits for it.
    std::thread::sleep(Duration::from_millis(500));
    let (o, took) = terminate(join);
    drop(s);
    deltaloop_supervisor::ops::loopback::remove_root(&root, false);
    let err = text(&o.stderr);
    assert!(took < Duration::from_secs(3), "{took:?}: {err}");
    assert_eq!(o.status.code(), Some(5), "{err}");
    assert!(err.contains("waiting for the near side's HELLO"), "{err}");
}

/// Regression: `join --runs 0` exited when a connector closed at once (or a second join raced
/// it); it keeps serving: it connects again after each, until it is stopped.
#[test]
fn regression_join_runs_0_keeps_serving_after_a_connection_closed_at_once() {
    let tmp = tempfile::tempdir().unwrap();
    let key = tmp.path().join("link.key");
    deltaloop_bridge::seal::LinkKey::write_new(&key).unwrap();
    let l = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let port = l.local_addr().unwrap().port();
    let root = tmp.path().join("far-root");
    let mut join = join_runs(port, &key, 0, &root);
    for _ in 0..2 {
        drop(accept_within(&l));
    }
    // Still serving: it comes back a third time (within the same run's join, as a near side
    // that closed a connection in the handshake may have been flooded).
    let third = accept_within(&l);
    assert!(join.try_wait().unwrap().is_none(), "join --runs 0 exited");
    // Stopped in the middle of that one's handshake: at once, and a stop.
    let (o, took) = terminate(join);
    drop(third);
    deltaloop_supervisor::ops::loopback::remove_root(&root, false);
    let err = text(&o.stderr);
    assert!(took < Duration::from_secs(3), "{took:?}: {err}");
    assert_eq!(o.status.code(), Some(5), "{err}");
    assert!(
        err.contains("closed the connection during the handshake; trying again"),
        "{err}"
    );
}

/// The shared-memory files of iceoryx2 root `root`.
fn shm_of(root: &Path) -> Vec<String> {
    let (_, prefix) = deltaloop_transport::ipc::root_of(root.to_str().unwrap()).unwrap();
    std::fs::read_dir("/dev/shm")
        .unwrap()
        .flatten()
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| n.starts_with(&prefix))
        .collect()
}

/// Regression: a far bridge killed with -9 left its shared memory (17 entries, 11 MiB) and its
/// temp folder, and later `join`s never removed them; the next `join` on that host does.
#[test]
fn regression_what_a_far_bridge_killed_outright_left_is_removed_by_the_next_join() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let (tmp, cfg, key, ep) = s1_with_key();
    let out = tmp.path().join("remote");
    // Long enough (20 s of hold) to be killed in the middle of.
    let mut args = remote_lockstep(&cfg, &ep, &key, &out).to_vec();
    args.extend(["--hold-s", "20"]);
    let run = common::spawn(&args);
    let far_root = tmp.path().join("far-root");
    let join = join_with(&ep, &key, &far_root);
    // Once the far side holds the run's services, it dies outright.
    let t0 = std::time::Instant::now();
    while shm_of(&far_root).len() < 5 {
        assert!(
            t0.elapsed() < Duration::from_secs(60),
            "the far side never opened the run's services"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
    std::thread::sleep(Duration::from_secs(1));
    // SAFETY: our own child (`join` exec'd the far bridge), not yet reaped.
    unsafe { libc::kill(join.id() as i32, libc::SIGKILL) };
    let _ = common::finish_within(join, Duration::from_secs(10), "the killed join");
    let _ = common::finish_within(run, Duration::from_secs(60), "deltaloop run");
    let left = shm_of(&far_root);
    assert!(!left.is_empty(), "nothing was left to remove");
    // The next join on this host, even one that reaches nobody, removes it first.
    let next = Command::new(env!("CARGO_BIN_EXE_deltaloop"))
        .args([
            "join",
            &format!("127.0.0.1:{}", free_port()),
            "--wait-s",
            "1",
        ])
        .args(["--link-key", key.to_str().unwrap()])
        .env("DELTALOOP_IOX2_ROOT", &far_root)
        .output()
        .unwrap();
    let err = text(&next.stderr);
    // Every resource of the dead nodes; iceoryx2's own management file of the root stays (the
    // new join made it, as any process of that root does).
    let after: Vec<String> = shm_of(&far_root)
        .into_iter()
        .filter(|n| !n.ends_with(".global_mgmt"))
        .collect();
    deltaloop_supervisor::ops::loopback::remove_root(&far_root, false);
    assert!(
        err.contains("removed what earlier far bridges killed outright left"),
        "{err}"
    );
    assert!(after.is_empty(), "of {left:?}, left: {after:?}");
}

/// Regression: the far side's process (the controller or the plant `join` starts, and any
/// `--controller-cmd`/`--plant-cmd`, third-party code) inherited `DELTALOOP_LINK_KEY`, the
/// long-lived link key, from the far bridge. A controller command that writes its environment
/// to a file, then runs the built-in controller, completes the run and was given no secret.
#[test]
fn regression_the_far_process_is_not_given_the_link_key() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let (tmp, cfg, key, ep) = s1_with_key();
    let seen = tmp.path().join("far-env.txt");
    let script = tmp.path().join("env-controller.sh");
    std::fs::write(
        &script,
        format!(
            "#!/bin/sh\nenv > '{}'\nexec '{}' \"$@\"\n",
            seen.display(),
            env!("CARGO_BIN_EXE_deltaloop-controller")
        ),
    )
    .unwrap();
    use std::os::unix::fs::PermissionsExt;
    std::fs::set_permissions(&script, std::fs::Permissions::from_mode(0o700)).unwrap();
    let out = tmp.path().join("remote");
    let run = common::spawn(&remote_lockstep(&cfg, &ep, &key, &out));
    let far_root = tmp.path().join("far-root");
    let join = join_with_cmd(&ep, &key, &far_root, &script.display().to_string());
    let (o, j) = finish_pair(run, join, &far_root);
    assert!(o.status.success(), "{}", text(&o.stderr));
    assert!(j.status.success(), "join: {}", text(&j.stderr));
    let env = std::fs::read_to_string(&seen).expect("the far controller wrote its environment");
    let hex = deltaloop_bridge::seal::LinkKey::read(&key)
        .unwrap()
        .to_hex();
    assert!(
        env.contains("DELTALOOP_IOX2_ROOT="),
        "the environment it reports: {env}"
    );
    assert!(
        !env.contains(deltaloop_bridge::seal::KEY_ENV) && !env.contains(&hex),
        "the far controller was given the link key: {env}"
    );
}

/// An attacker on this machine's loopback (root: AF_PACKET and a raw socket): it reads the
/// first datagram the near bridge (port `argv[1]`) sends the far one, then sends the far bridge
/// that datagram again (a replay), a copy with a byte of its sealed payload flipped (a forgery)
/// and a copy with another session id (another run), five of each, from the near bridge's
/// address and port.
const LOOPBACK_ATTACKER: &str = r#"
import socket, struct, sys, time
port = int(sys.argv[1])
cap = socket.socket(socket.AF_PACKET, socket.SOCK_RAW, socket.ntohs(3))
cap.bind(("lo", 0))
cap.settimeout(120)
while True:
    f = cap.recv(4096)
    if f[12:14] != b"\x08\x00" or f[14 + 9] != 17:
        continue
    ip = f[14:]
    ihl = (ip[0] & 15) * 4
    sport, dport, ulen = struct.unpack("!HHH", ip[ihl:ihl + 6])
    payload = ip[ihl + 8:ihl + ulen]
    if sport == port and dport != port and payload[:4] == b"DLB2":
        break
raw = socket.socket(socket.AF_INET, socket.SOCK_RAW, socket.IPPROTO_RAW)
lo = socket.inet_aton("127.0.0.1")
def send(data):
    udp = struct.pack("!HHHH", port, dport, 8 + len(data), 0) + data
    iph = struct.pack("!BBHHHBBH4s4s", 0x45, 0, 20 + len(udp), 0, 0, 64, 17, 0, lo, lo)
    raw.sendto(iph + udp, ("127.0.0.1", 0))
forged = bytearray(payload); forged[30] ^= 0x40
other = bytearray(payload); other[8] ^= 1
for _ in range(5):
    send(payload); send(bytes(forged)); send(bytes(other))
    time.sleep(0.05)
print("sent", len(payload))
"#;

/// Regression: with `--plant-remote` the far host is the robot's, and the datagrams refused
/// there (forged, replayed, of another run) were in no record: `summary.json` said 0 and
/// nothing warned. Injected on the far bridge's socket during a run, they are refused, the far
/// side reports them over the sealed control channel at the end of the run, and they are in
/// `summary.json` (`link_security.far`, and in the totals), `report.md`, the supervisor's
/// warning and a warning on `join`'s terminal.
#[test]
fn regression_the_far_hosts_refused_datagrams_are_in_the_runs_record() {
    let name = "regression_the_far_hosts_refused_datagrams_are_in_the_runs_record";
    // SAFETY: geteuid has no preconditions.
    if unsafe { libc::geteuid() } != 0 {
        eprintln!("SKIPPED {name}: needs root to play the attacker (AF_PACKET, a raw socket)");
        return;
    }
    if Command::new("python3").arg("-V").output().is_err() {
        eprintln!("SKIPPED {name}: needs python3 (its socket module) to play the attacker");
        return;
    }
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let (tmp, cfg, key, ep) = s1_with_key();
    let port = ep.rsplit_once(':').unwrap().1.to_string();
    let attacker = Command::new("python3")
        .args(["-c", LOOPBACK_ATTACKER, &port])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let out = tmp.path().join("remote");
    let mut args = remote_lockstep(&cfg, &ep, &key, &out).to_vec();
    args[4] = "--plant-remote";
    args.extend(["--hold-s", "3"]);
    let run = common::spawn(&args);
    let far_root = tmp.path().join("far-root");
    let join = Command::new(env!("CARGO_BIN_EXE_deltaloop"))
        .args(["join", &ep, "--role", "plant", "--wait-s", "60"])
        .args(["--link-key", key.to_str().unwrap()])
        .env("DELTALOOP_IOX2_ROOT", &far_root)
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let o = common::finish_within(run, Duration::from_secs(120), "deltaloop run");
    let j = common::finish_within(join, Duration::from_secs(30), "join");
    let a = common::finish_within(attacker, Duration::from_secs(30), "the attacker");
    deltaloop_supervisor::ops::loopback::remove_root(&far_root, false);
    let (run_err, join_err) = (text(&o.stderr), text(&j.stderr));
    assert!(a.status.success(), "attacker: {}", text(&a.stderr));
    assert!(o.status.success(), "{run_err}");
    assert!(j.status.success(), "join: {join_err}");
    let s = summary(&out);
    let sec = &s["timing"]["tdc"]["link_security"];
    let far = &sec["far"]["refused_datagrams"];
    for reason in ["replayed", "forged", "other_run"] {
        assert_eq!(far[reason], 5, "{reason}: {sec}");
        // The totals (today's keys) count both hosts.
        assert_eq!(sec["refused_datagrams"][reason], 5, "{reason}: {sec}");
    }
    assert_eq!(sec["near"]["refused_datagrams"]["forged"], 0, "{sec}");
    let report = std::fs::read_to_string(out.join("report.md")).unwrap();
    let far_line = "on the far host: malformed 0, other run 5, forged 5, replayed 5";
    assert!(report.contains(far_line), "{report}");
    assert!(
        run_err.contains("15 datagram(s) during the run") && run_err.contains(far_line),
        "{run_err}"
    );
    assert!(
        join_err.contains("warning: refused 15 datagram(s) on the link"),
        "{join_err}"
    );
}

/// Regression: a near side busy with a flood of connections without the key dropped an honest
/// `join` unheard, and `join` (any `--runs` but 0) gave up, blaming the key ("does it hold this
/// link key?"). The busy notice has `join --runs 1` say the near side is busy and connect again,
/// and the handshake that follows succeeds.
#[test]
fn regression_join_tries_a_busy_near_side_again_and_does_not_blame_the_key() {
    let tmp = tempfile::tempdir().unwrap();
    let key = tmp.path().join("link.key");
    let k = deltaloop_bridge::seal::LinkKey::write_new(&key).unwrap();
    let l = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let port = l.local_addr().unwrap().port();
    let root = tmp.path().join("far-root");
    let join = join_runs(port, &key, 1, &root);
    let first = accept_within(&l);
    deltaloop_bridge::seal::busy(&first);
    first.shutdown(std::net::Shutdown::Write).unwrap();
    let again = accept_within(&l);
    let joined = joins(again, &k);
    let (o, _) = terminate(join);
    drop(first);
    deltaloop_supervisor::ops::loopback::remove_root(&root, false);
    let err = text(&o.stderr);
    assert!(joined, "no JOIN came: {err}");
    assert!(
        err.contains("is busy authenticating other connections"),
        "{err}"
    );
    assert!(
        err.contains("trying again") && err.contains("joined the run"),
        "{err}"
    );
    assert!(!err.contains("link key?"), "{err}");
}

/// Whether the far side on `s` proves `key` and sends its JOIN (within 30 s), as a near side
/// would have it: the event after which `join` says it joined the run.
fn joins(mut s: std::net::TcpStream, key: &deltaloop_bridge::seal::LinkKey) -> bool {
    use deltaloop_bridge::{frame::Kind, link::Tcp, seal};
    let session = seal::Session::generate().unwrap();
    if seal::respond(&mut s, key, &session, Duration::from_secs(10)).is_err() {
        return false;
    }
    let mut tcp = Tcp::new(s, &session, seal::End::Near).unwrap();
    let t0 = std::time::Instant::now();
    while t0.elapsed() < Duration::from_secs(30) && !tcp.closed {
        let mut join = false;
        let heard = tcp.poll(|k, _| {
            join |= k == Kind::Join;
            Ok(())
        });
        if heard.is_err() {
            return false;
        }
        if join {
            return true;
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    false
}

/// Regression: a near side that closed the connection in the handshake (as a loaded one does
/// at its 2 s deadline) or did not answer in time ended `join --runs 1`, and a closed
/// connection was blamed on the key ("does it hold this link key?"). `join` tries again until
/// `--wait-s` runs out, says what happened without naming the key, and joins when it can.
#[test]
fn regression_join_tries_again_when_the_near_side_closes_or_times_out() {
    let tmp = tempfile::tempdir().unwrap();
    let key = tmp.path().join("link.key");
    let k = deltaloop_bridge::seal::LinkKey::write_new(&key).unwrap();
    let l = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let port = l.local_addr().unwrap().port();
    let root = tmp.path().join("far-root");
    let join = join_runs(port, &key, 1, &root);
    // Closed once its first message came; then silent until join's 2 s ran out.
    let mut first = accept_within(&l);
    let mut m = [0u8; 2];
    std::io::Read::read_exact(&mut first, &mut m).unwrap();
    drop(first);
    let silent = accept_within(&l);
    let joined = joins(accept_within(&l), &k);
    let (o, _) = terminate(join);
    drop(silent);
    deltaloop_supervisor::ops::loopback::remove_root(&root, false);
    let err = text(&o.stderr);
    assert!(joined, "no JOIN came: {err}");
    for said in [
        "closed the connection during the handshake; trying again",
        "did not complete the handshake within 2 s; trying again",
        "joined the run",
    ] {
        assert!(err.contains(said), "{said}: {err}");
    }
    assert!(!err.contains("link key?"), "{err}");
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

/// The pid of `parent`'s child whose command line says `deltaloop-bridge near`, within 30 s.
fn near_bridge_of(parent: u32) -> i32 {
    let t0 = std::time::Instant::now();
    loop {
        for e in std::fs::read_dir("/proc").unwrap().flatten() {
            let Ok(pid) = e.file_name().to_string_lossy().parse::<i32>() else {
                continue;
            };
            let stat = std::fs::read_to_string(e.path().join("stat")).unwrap_or_default();
            // The parent is the second field after the command's closing parenthesis.
            let ppid = stat
                .rsplit_once(") ")
                .and_then(|(_, rest)| rest.split(' ').nth(1))
                .and_then(|p| p.parse::<u32>().ok());
            let cmd = std::fs::read(e.path().join("cmdline")).unwrap_or_default();
            if ppid == Some(parent) && text(&cmd).contains("deltaloop-bridge\0near") {
                return pid;
            }
        }
        assert!(
            t0.elapsed() < Duration::from_secs(30),
            "no near bridge under {parent}"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// Regression: a bridge held up for 30–300 ms mid-run (SIGSTOP: its host did not run it) left
/// a record that `replay` could not reproduce. The near side sent the plant's backlog of states
/// on at once, the far controller answered each, and the burst of replies overflowed the near
/// side's socket: states the controller had answered were recorded as unanswered ("ok, lost 0",
/// then "trace.csv differs"). And a late reply to the tick the plant stopped at (the controller
/// silence that followed) made a row with `reply` unknown, which the replay refused as a lost
/// tick. Each bridge of each role in turn is stalled five times for 200 ms: the run replays byte for byte,
/// or the replay refuses exactly the ticks the summary counts as lost. On the relay path the stall
/// reaches the loop; on the direct path (the loop's messages do not pass a bridge) it must not:
/// only the record's copies wait.
#[test]
fn regression_a_stalled_bridge_run_replays_or_says_what_it_lost() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    for (role, stalled, path) in [
        ("controller", "near", "relay"),
        ("controller", "far", "relay"),
        ("plant", "near", "relay"),
        ("plant", "far", "relay"),
        ("controller", "near", "direct"),
    ] {
        {
            let (tmp, cfg, key, ep) = s1_with_key();
            let out = tmp.path().join("run");
            let remote = format!("--{role}-remote");
            let s = |p: &Path| p.to_str().unwrap().to_string();
            let args = [
                "run",
                &s(&cfg),
                "--mode",
                "realtime",
                &remote,
                &ep,
                "--link-key",
                &s(&key),
                "--hold-s",
                "4",
                "--link-path",
                path,
                "--out",
                &s(&out),
            ];
            let run = common::spawn(&args);
            let near = near_bridge_of(run.id());
            let far_root = tmp.path().join("far-root");
            let join = join_as(&ep, role, &key, &far_root);
            // `join` exec'd the far bridge: its pid is the far bridge's.
            let pid = if stalled == "near" {
                near
            } else {
                join.id() as i32
            };
            let log = out.join(format!("tdc.{role}.log"));
            let t0 = std::time::Instant::now();
            while !std::fs::read_to_string(&log).is_ok_and(|l| l.contains("joined")) {
                assert!(t0.elapsed() < Duration::from_secs(60), "nobody joined");
                std::thread::sleep(Duration::from_millis(20));
            }
            // START, and some of the loop; then, five times, the bridge's host does not run it
            // for 200 ms (one stall lost replies in about a third of the runs before the fix).
            std::thread::sleep(Duration::from_millis(600));
            for _ in 0..5 {
                std::thread::sleep(Duration::from_millis(500));
                // SAFETY: a process of this test's (the run's child, or join's exec).
                unsafe { libc::kill(pid, libc::SIGSTOP) };
                std::thread::sleep(Duration::from_millis(200));
                unsafe { libc::kill(pid, libc::SIGCONT) };
            }
            let (o, _) = finish_pair(run, join, &far_root);
            let case = format!("{role} remote, {stalled} bridge stalled, {path} path");
            let trace = rows(&out.join("trace.csv"));
            assert!(!trace.is_empty(), "{case}: no trace: {}", text(&o.stderr));
            // On the relay path the stall hit the loop: a stretch of ticks the plant got no reply
            // for in time (each stall is ≈ 667 ticks). On the direct path it did not.
            let longest = trace
                .split(|r| r["reply"] == "applied")
                .map(<[_]>::len)
                .max()
                .unwrap_or(0);
            if path == "relay" {
                assert!(longest >= 300, "{case}: no stall in the trace ({longest})");
            } else {
                assert!(
                    longest < 300,
                    "{case}: the bridge's stall reached the loop ({longest})"
                );
            }
            let whole = replays_or_names_what_it_lost(&case, &out, &tmp.path().join("replay"));
            assert!(whole || path == "relay", "{case}: the record lost ticks");
        }
    }
}

/// `deltaloop replay OUT --out REPLAY`: the run reproduces byte for byte (true), or the replay
/// refuses it for ticks the record says it lost, and names (false). Anything else fails `case`.
fn replays_or_names_what_it_lost(case: &str, out: &Path, replay: &Path) -> bool {
    let s = |p: &Path| p.to_str().unwrap().to_string();
    let r = common::deltaloop(&["replay", &s(out), "--out", &s(replay)]);
    let said = text(&r.stdout) + &text(&r.stderr);
    eprintln!("{case}: {}", said.trim_end());
    if r.status.success() {
        assert!(said.contains("reproduced byte for byte"), "{case}: {said}");
        return true;
    }
    // Refused: only for ticks the record says it lost, and names.
    let lost = said
        .split_once("the run lost ticks ")
        .and_then(|(_, t)| t.split_once(' '))
        .and_then(|(range, _)| range.split_once(".."))
        .and_then(|(a, b)| Some((a.parse::<u64>().ok()?, b.parse::<u64>().ok()?)));
    let Some((first, last)) = lost else {
        panic!("{case}: the replay differs from the record: {said}");
    };
    let law = &summary(out)["laws"]["tdc"];
    let counted = ["lost_ticks", "telemetry_missing", "replies_lost"]
        .iter()
        .map(|k| law[k].as_u64().unwrap_or(0))
        .sum::<u64>();
    assert!(
        law["status"] != "ok" && counted > last - first,
        "{case}: replay refused ticks {first}..{last}, the summary: {law}"
    );
    let named =
        law["lost_data"].as_str().unwrap_or("").to_string() + law["reason"].as_str().unwrap_or("");
    assert!(named.contains(&format!("tick {first}")), "{case}: {law}");
    false
}

/// Regression: more than three reply datagrams in a row lost on the link (a burst, here the
/// emulated `[link] loss` of 30 %) lost replies the far controller had computed: the record
/// filed those ticks as `missed`, the replay's controller did not step on them, and its torque
/// differed from the next answered tick on ("trace.csv differs", while the summary said the run
/// was fine). The near bridge now sees the hole in the replies' numbers and recalls it from the
/// far side's ring over the control connection, or tells the supervisor which ticks' replies are
/// unknown: the run replays byte for byte, or the replay refuses exactly the ticks the summary
/// counts as lost.
#[test]
fn regression_a_burst_of_lost_replies_is_recovered_or_recorded_as_lost() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let (tmp, cfg, key, ep) = s1_with_key();
    let out = tmp.path().join("run");
    let s = |p: &Path| p.to_str().unwrap().to_string();
    let args = [
        "run",
        &s(&cfg),
        "--mode",
        "realtime",
        "--controller-remote",
        &ep,
        "--link-key",
        &s(&key),
        "--link-loss",
        "0.3",
        "--link-seed",
        "7",
        "--hold-s",
        "1",
        "--link-path",
        "relay",
        "--out",
        &s(&out),
    ];
    let run = common::spawn(&args);
    let far_root = tmp.path().join("far-root");
    let join = join_as(&ep, "controller", &key, &far_root);
    let (o, j) = finish_pair(run, join, &far_root);
    let case = "30 % of the link's datagrams lost";
    assert!(
        out.join("trace.csv").is_file(),
        "{case}: no trace: {}",
        text(&o.stderr)
    );
    let whole = replays_or_names_what_it_lost(case, &out, &tmp.path().join("replay"));
    // The loss made bursts beyond the copies, and the near bridge recalled them.
    let log = std::fs::read_to_string(out.join("tdc.controller.log")).unwrap_or_default();
    let beyond = log
        .split_once(" lost beyond its copies (")
        .and_then(|(before, after)| {
            let lost = before.rsplit(' ').next()?.parse::<u64>().ok()?;
            let recalled = after.split(' ').next()?.parse::<u64>().ok()?;
            Some((lost, recalled))
        });
    let Some((lost, recalled)) = beyond else {
        panic!("{case}: the near bridge's link line is missing: {log}");
    };
    assert!(lost > 0, "{case}: no burst beyond the copies: {log}");
    assert!(
        recalled == lost || !whole,
        "{case}: {lost} lost beyond the copies, {recalled} recalled, and the run replayed whole"
    );
    eprintln!(
        "{case}: {lost} repl(ies) lost beyond the copies, {recalled} recalled; join: {}",
        text(&j.stderr).trim_end()
    );
    // The direct path: the same loss on the plant's and the controller's own sockets; the record
    // takes every reply from the far side over the control connection, so the run replays whole.
    let out = tmp.path().join("direct");
    let mut args = args.map(str::to_string);
    let n = args.len();
    (args[n - 3], args[n - 1]) = ("direct".into(), s(&out));
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    let run = common::spawn(&args);
    let join = join_as(&ep, "controller", &key, &far_root);
    let (o, _) = finish_pair(run, join, &far_root);
    let case = "30 % lost, direct path";
    assert!(
        out.join("trace.csv").is_file(),
        "{case}: {}",
        text(&o.stderr)
    );
    let plant_log = std::fs::read_to_string(out.join("tdc.plant.log")).unwrap_or_default();
    assert!(
        replays_or_names_what_it_lost(case, &out, &tmp.path().join("replay-direct")),
        "{case}: the record lost replies: {plant_log}"
    );
}

/// Regression: a far controller whose step reported an error (it said CONTROLLER_ERROR) stopped
/// a lockstep loop only after the plant's silence timeout (2 s): the near bridge passed the
/// message on but did not wake the plant, which reads it when it wakes. The plant stops at the
/// failing tick at once, naming the error, as on one host.
#[test]
fn regression_a_far_controller_step_error_stops_the_lockstep_loop_at_once() {
    let Some(exe) = common::c_peer("c_controller_faults") else {
        return;
    };
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let (tmp, cfg, key, ep) = s1_with_key();
    let out = tmp.path().join("remote");
    let run = common::spawn(&remote_lockstep(&cfg, &ep, &key, &out));
    let far_root = tmp.path().join("far-root");
    let join = join_with_cmd(&ep, &key, &far_root, &format!("{} fail@200", exe.display()));
    let (o, _) = finish_pair(run, join, &far_root);
    assert_eq!(o.status.code(), Some(1), "{}", text(&o.stderr));
    common::assert_step_error_stopped_the_loop_at_once(
        &out,
        "the controller reported an error at tick 200",
    );
}

/// Regression: with the plant remote, a controller whose step reported an error (it said
/// CONTROLLER_ERROR) stopped the far lockstep plant only after its silence timeout (2 s): the
/// far bridge republished the message there but did not wake the plant, which reads it when it
/// wakes. The far plant stops at the failing tick at once, naming the error, as on one host.
#[test]
fn regression_a_controller_step_error_stops_a_far_lockstep_plant_at_once() {
    let Some(exe) = common::c_peer("c_controller_faults") else {
        return;
    };
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let (tmp, cfg, key, ep) = s1_with_key();
    let out = tmp.path().join("remote");
    let s = |p: &Path| p.to_str().unwrap().to_string();
    let controller = format!("--controller-cmd={} fail@200", exe.display());
    let args = [
        "run",
        &s(&cfg),
        "--mode",
        "lockstep",
        "--plant-remote",
        &ep,
        "--link-key",
        &s(&key),
        &controller,
        "--out",
        &s(&out),
    ];
    let run = common::spawn(&args);
    let far_root = tmp.path().join("far-root");
    let join = join_as(&ep, "plant", &key, &far_root);
    let (o, _) = finish_pair(run, join, &far_root);
    assert_eq!(o.status.code(), Some(1), "{}", text(&o.stderr));
    common::assert_step_error_stopped_the_loop_at_once(
        &out,
        "the controller reported an error at tick 200",
    );
}

/// Regression: a foreign controller on the far host was not labelled on the supervisor's host:
/// the label falls back to the run's `controller.command`, which with `--controller-remote` is
/// empty (the command is `join --controller-cmd`'s). The far bridge names a controller that
/// does not name itself in its READY after its command, as a local one is named: the terminal
/// table, summary.json and report.md show it.
#[test]
fn regression_a_far_controller_of_the_users_is_labelled_on_the_supervisors_host() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let (tmp, cfg, key, ep) = s1_with_key();
    // The built-in controller under a name of this test's (it says nothing in its READY).
    let named = tmp.path().join("rig-law-7");
    std::os::unix::fs::symlink(env!("CARGO_BIN_EXE_deltaloop-controller"), &named).unwrap();
    let out = tmp.path().join("remote");
    let run = common::spawn(&remote_lockstep(&cfg, &ep, &key, &out));
    let far_root = tmp.path().join("far-root");
    let join = join_with_cmd(&ep, &key, &far_root, named.to_str().unwrap());
    let (o, j) = finish_pair(run, join, &far_root);
    assert!(o.status.success(), "{}", text(&o.stderr));
    assert!(j.status.success(), "join: {}", text(&j.stderr));
    assert_eq!(summary(&out)["controller_label"], "rig-law-7");
    let stdout = text(&o.stdout);
    assert!(stdout.contains("tdc (rig-law-7)"), "{stdout}");
    let report = std::fs::read_to_string(out.join("report.md")).unwrap();
    assert!(report.contains("Controller: `rig-law-7`"), "{report}");
}

/// Regression (`--plant-remote`): the near bridge moved each state's stamps onto this host's
/// clock by that state's own delay, so after a 200 ms stall of the near bridge every later
/// deadline moved by the stall, the controller's schedule followed, and no reply was applied
/// again (300 missed, 3 skipped, 1 late, repeating) until the silence fault. The stamps move by
/// the clocks' offset: the loop applies replies again after the stall. Judged against the same
/// run before the stall, so a host that disturbs the whole run says nothing (run again).
#[test]
fn regression_a_remote_plant_loop_recovers_after_a_near_bridge_stall() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    common::on_a_noisy_host(
        "a_remote_plant_loop_recovers_after_a_near_bridge_stall",
        |_| {
            let (tmp, cfg, key, ep) = s1_with_key();
            let out = tmp.path().join("run");
            let s = |p: &Path| p.to_str().unwrap().to_string();
            let args = [
                "run",
                &s(&cfg),
                "--mode",
                "realtime",
                "--plant-remote",
                &ep,
                "--link-key",
                &s(&key),
                "--hold-s",
                "4",
                "--link-path",
                "relay",
                "--out",
                &s(&out),
            ];
            let run = common::spawn(&args);
            let near = near_bridge_of(run.id());
            let far_root = tmp.path().join("far-root");
            let join = join_as(&ep, "plant", &key, &far_root);
            let log = out.join("tdc.plant.log");
            let t0 = std::time::Instant::now();
            while !std::fs::read_to_string(&log).is_ok_and(|l| l.contains("joined")) {
                assert!(t0.elapsed() < Duration::from_secs(60), "nobody joined");
                std::thread::sleep(Duration::from_millis(20));
            }
            // Three stalls of 200 ms, 0.8 s apart (one left the loop unrecovered in about half
            // the runs before the fix).
            std::thread::sleep(Duration::from_millis(1000));
            for _ in 0..3 {
                // SAFETY: the run's child, the near bridge.
                unsafe { libc::kill(near, libc::SIGSTOP) };
                std::thread::sleep(Duration::from_millis(200));
                unsafe { libc::kill(near, libc::SIGCONT) };
                std::thread::sleep(Duration::from_millis(600));
            }
            let (o, _) = finish_pair(run, join, &far_root);
            let trace = rows(&out.join("trace.csv"));
            assert!(!trace.is_empty(), "no trace: {}", text(&o.stderr));
            let applied: Vec<bool> = trace.iter().map(|r| r["reply"] == "applied").collect();
            let share =
                |r: &[bool]| r.iter().filter(|a| **a).count() as f64 / r.len().max(1) as f64;
            // Before the first stall (the first 0.9 s of the loop), and the last second of the run,
            // which must have come (S1 + 4 s hold: 16,001 ticks).
            let before = share(&applied[..3000.min(applied.len())]);
            let last = share(&applied[applied.len().saturating_sub(3333)..]);
            eprintln!(
                "{} ticks; {before:.2} applied before the stalls, {last:.2} in the last second",
                applied.len()
            );
            if before < 0.5 {
                return Err(format!(
                    "the loop was already disturbed: {before:.2} applied before"
                ));
            }
            assert!(
                applied.len() == 16_001 && last > 0.5,
                "{before:.2} of the replies applied before the stalls, {last:.2} in the last second of {} ticks: {}",
                applied.len(),
                text(&o.stderr)
            );
            Ok(())
        },
    );
}

/// Regression: with `--controller-remote`, a near bridge its host held up for about 3 s lost
/// reply copies without a word: the supervisor had finished those ticks (or its queue had
/// overflowed) before the copies came, so the run said `ok`, `replies_lost` 0, hundreds of rows
/// "missed" that the far controller had answered, and `replay` "differs at tick 3145". The near
/// bridge knows when it was held up past what the record can wait for, and tells the
/// supervisor which ticks' replies it cannot file (REPLIES_LOST): the run is `lost_data` with
/// them counted, and the replay refuses exactly those ticks, as with a stalled `--plant-remote`.
/// About 15 s: `cargo test --test e2e link_loopback::regression_a_near_bridge_held_up_3_s -- --ignored`.
#[test]
#[ignore = "a 3 s stall in a 7 s run: see docs/guide/failure-behaviour.md"]
fn regression_a_near_bridge_held_up_3_s_loses_no_reply_copy_silently() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let RemoteController {
        tmp,
        out,
        run,
        near,
        join,
        far_root,
        log,
    } = remote_controller_started(&["--hold-s", "6"]);
    std::thread::sleep(Duration::from_millis(1000));
    // SAFETY: the run's child, the near bridge.
    unsafe { libc::kill(near, libc::SIGSTOP) };
    std::thread::sleep(Duration::from_millis(3000));
    unsafe { libc::kill(near, libc::SIGCONT) };
    let (o, _) = finish_pair(run, join, &far_root);
    let law = &summary(&out)["laws"]["tdc"];
    eprintln!("{law}\n{}", text(&o.stderr));
    assert_eq!(law["status"], "lost_data", "{law}");
    assert!(law["replies_lost"].as_u64().unwrap_or(0) > 0, "{law}");
    let whole =
        replays_or_names_what_it_lost("near bridge held up 3 s", &out, &tmp.path().join("replay"));
    assert!(!whole, "the replay reproduced a run that lost replies");
    let log = std::fs::read_to_string(&log).unwrap();
    assert!(log.contains("had finished those ticks"), "{log}");
}

/// Regression: a near bridge killed with -9 in a `--controller-remote` run was reported as
/// "the controller was killed (SIGKILL)", though the controller on the other host was fine.
/// The run's reason names the bridge.
#[test]
fn regression_a_killed_near_bridge_is_named_not_the_controller() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let RemoteController {
        tmp: _tmp,
        out,
        run,
        near,
        join,
        far_root,
        ..
    } = remote_controller_started(&[]);
    std::thread::sleep(Duration::from_millis(300));
    // SAFETY: the run's child, the near bridge.
    unsafe { libc::kill(near, libc::SIGKILL) };
    let (o, _) = finish_pair(run, join, &far_root);
    let law = &summary(&out)["laws"]["tdc"];
    let reason = law["reason"].as_str().unwrap_or("");
    assert!(
        reason.contains("near bridge") && reason.contains("SIGKILL"),
        "{law}\n{}",
        text(&o.stderr)
    );
    assert!(!reason.contains("the controller was killed"), "{reason}");
}

/// Regression: the near side counts a connection as having proved the key only by its first
/// sealed frame (a replayed first handshake message proves nothing), so a flood can drop an
/// honest one for room after answering its handshake, before reading its JOIN. `join` heard the
/// busy notice where it waited for the HELLO, said "sent no HELLO" and gave up; it connects
/// again, as for any busy near side.
#[test]
fn regression_join_dropped_for_room_after_the_handshake_tries_again() {
    use deltaloop_bridge::seal;
    let tmp = tempfile::tempdir().unwrap();
    let key = tmp.path().join("link.key");
    let k = seal::LinkKey::write_new(&key).unwrap();
    let l = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let port = l.local_addr().unwrap().port();
    let root = tmp.path().join("far-root");
    let join = join_runs(port, &key, 1, &root);
    let mut first = accept_within(&l);
    let session = seal::Session::generate().unwrap();
    seal::respond(&mut first, &k, &session, Duration::from_secs(10)).unwrap();
    seal::busy(&first);
    first.shutdown(std::net::Shutdown::Both).unwrap();
    let joined = joins(accept_within(&l), &k);
    let (o, _) = terminate(join);
    drop(first);
    deltaloop_supervisor::ops::loopback::remove_root(&root, false);
    let err = text(&o.stderr);
    assert!(joined, "no JOIN came: {err}");
    assert!(err.contains("trying again"), "{err}");
    assert!(
        !err.contains("sent no HELLO") && !err.contains("link key?"),
        "{err}"
    );
}

/// The port the UDP socket bound at 127.0.0.1:`port` is connected to (from /proc/net/udp),
/// within 30 s.
fn udp_peer_of(port: u16) -> u16 {
    let local = format!("0100007F:{port:04X}");
    let t0 = std::time::Instant::now();
    loop {
        let table = std::fs::read_to_string("/proc/net/udp").unwrap_or_default();
        for line in table.lines().skip(1) {
            let f: Vec<&str> = line.split_whitespace().collect();
            if f.get(1) == Some(&local.as_str())
                && let Some((_, p)) = f.get(2).and_then(|r| r.split_once(':'))
                && let Ok(p) = u16::from_str_radix(p, 16)
                && p != 0
            {
                return p;
            }
        }
        assert!(
            t0.elapsed() < Duration::from_secs(30),
            "no connected socket on {port}"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// An ICMP port unreachable (type 3, code 3) to 127.0.0.1 quoting a UDP datagram from
/// 127.0.0.1:`from` to 127.0.0.1:`to`, as anyone who knows the link's addresses can send it.
fn icmp_port_unreachable(raw: i32, from: u16, to: u16) {
    let sum = |b: &[u8]| {
        let mut s: u32 = b
            .chunks(2)
            .map(|c| u32::from(u16::from_be_bytes([c[0], *c.get(1).unwrap_or(&0)])))
            .sum();
        while s > 0xffff {
            s = (s & 0xffff) + (s >> 16);
        }
        !(s as u16)
    };
    let mut ip = [
        0x45,
        0,
        0,
        28 + 168,
        0,
        0,
        0x40,
        0,
        64,
        17,
        0,
        0,
        127,
        0,
        0,
        1,
        127,
        0,
        0,
        1,
    ];
    let c = sum(&ip).to_be_bytes();
    ip[10..12].copy_from_slice(&c);
    let mut m = vec![3u8, 3, 0, 0, 0, 0, 0, 0];
    m.extend_from_slice(&ip);
    m.extend_from_slice(&from.to_be_bytes());
    m.extend_from_slice(&to.to_be_bytes());
    m.extend_from_slice(&[0, 176, 0, 0]);
    let c = sum(&m).to_be_bytes();
    m[2..4].copy_from_slice(&c);
    let to = libc::sockaddr_in {
        sin_family: libc::AF_INET as libc::sa_family_t,
        sin_port: 0,
        sin_addr: libc::in_addr {
            s_addr: u32::from_ne_bytes([127, 0, 0, 1]),
        },
        sin_zero: [0; 8],
    };
    // SAFETY: a valid buffer and sockaddr_in of the given lengths.
    unsafe {
        libc::sendto(
            raw,
            m.as_ptr().cast(),
            m.len(),
            0,
            (&raw const to).cast(),
            size_of::<libc::sockaddr_in>() as libc::socklen_t,
        )
    };
}

/// Regression: ICMP port unreachable messages quoting the plant's socket's addresses (from
/// anyone, no key, about the loop's own rate) set an error on the connected socket that made
/// the next send fail, taken for sent: 40 % of the ticks missed, the run `ok` with
/// `link_security` all zero. The send is made again and the errors counted. Needs root (a raw
/// socket); about 10 s:
/// `cargo test --test e2e link_loopback::regression_icmp_errors_on_the_link -- --ignored`.
#[test]
#[ignore = "a raw-socket ICMP flood, as root: see docs/guide/failure-behaviour.md"]
fn regression_icmp_errors_on_the_link_drop_no_datagram_and_are_counted() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    // SAFETY: a new raw socket, owned here and closed at the end.
    let raw = unsafe { libc::socket(libc::AF_INET, libc::SOCK_RAW, libc::IPPROTO_ICMP) };
    if raw < 0 {
        eprintln!("SKIPPED: no raw socket (not root)");
        return;
    }
    let (tmp, cfg, key, ep) = s1_with_key();
    let port: u16 = ep.rsplit_once(':').unwrap().1.parse().unwrap();
    let out = tmp.path().join("run");
    let s = |p: &Path| p.to_str().unwrap().to_string();
    let args = [
        "run",
        &s(&cfg),
        "--mode",
        "realtime",
        "--controller-remote",
        &ep,
        "--link-key",
        &s(&key),
        "--hold-s",
        "3",
        "--out",
        &s(&out),
    ];
    let run = common::spawn(&args);
    let far_root = tmp.path().join("far-root");
    let join = join_as(&ep, "controller", &key, &far_root);
    let log = out.join("tdc.controller.log");
    let t0 = std::time::Instant::now();
    while !std::fs::read_to_string(&log).is_ok_and(|l| l.contains("direct path")) {
        assert!(
            t0.elapsed() < Duration::from_secs(60),
            "the loop never started"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
    let far = udp_peer_of(port);
    // About 5,000 a second for 2 s.
    let t0 = std::time::Instant::now();
    while t0.elapsed() < Duration::from_secs(2) {
        for _ in 0..5 {
            icmp_port_unreachable(raw, port, far);
        }
        std::thread::sleep(Duration::from_millis(1));
    }
    // SAFETY: the raw socket opened above.
    unsafe { libc::close(raw) };
    let (o, _) = finish_pair(run, join, &far_root);
    let law = &summary(&out)["laws"]["tdc"];
    let sec = &summary(&out)["timing"]["tdc"]["link_security"];
    eprintln!("{law}\n{sec}");
    assert_eq!(law["status"], "ok", "{law}\n{}", text(&o.stderr));
    assert!(sec["icmp_errors"].as_u64().unwrap_or(0) > 100, "{sec}");
    let trace = rows(&out.join("trace.csv"));
    let missed = trace.iter().filter(|r| r["reply"] != "applied").count();
    assert!(
        missed * 20 < trace.len(),
        "{missed} of {} ticks missed",
        trace.len()
    );
}

/// A realtime S1 run with its controller joined from "the other host" (loopback), once the loop
/// runs on the direct path: the run, its near bridge's pid, the join and where things are.
struct RemoteController {
    tmp: tempfile::TempDir,
    out: PathBuf,
    run: std::process::Child,
    near: i32,
    join: std::process::Child,
    far_root: PathBuf,
    /// The law's controller log (the near bridge's words).
    log: PathBuf,
}

fn remote_controller_started(extra: &[&str]) -> RemoteController {
    let (tmp, cfg, key, ep) = s1_with_key();
    let out = tmp.path().join("run");
    let s = |p: &Path| p.to_str().unwrap().to_string();
    let (cfg, key_s, out_s) = (s(&cfg), s(&key), s(&out));
    let mut args = vec![
        "run",
        &cfg,
        "--mode",
        "realtime",
        "--controller-remote",
        &ep,
        "--link-key",
        &key_s,
    ];
    args.extend_from_slice(extra);
    args.extend_from_slice(&["--out", &out_s]);
    let run = common::spawn(&args);
    let near = near_bridge_of(run.id());
    let far_root = tmp.path().join("far-root");
    let join = join_as(&ep, "controller", &key, &far_root);
    let log = out.join("tdc.controller.log");
    let t0 = std::time::Instant::now();
    while !std::fs::read_to_string(&log).is_ok_and(|l| l.contains("direct path")) {
        assert!(
            t0.elapsed() < Duration::from_secs(60),
            "the loop never started"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
    RemoteController {
        tmp,
        out,
        run,
        near,
        join,
        far_root,
        log,
    }
}
