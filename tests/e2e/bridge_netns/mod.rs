//! A run split over two "hosts": two network namespaces of this machine joined by a veth pair,
//! each side with its own iceoryx2 root (`DELTALOOP_IOX2_ROOT`), so `deltaloop-bridge` is the only
//! path between the plant's side and the controller's. Needs root and `ip` (iproute2); where
//! namespaces cannot be made the test says what it needs on stderr and returns early (it does
//! not pretend to have checked anything); `DELTALOOP_REQUIRE_NETNS=1` turns such a skip into a
//! failure, for a machine that must run them.

use crate::common;
use std::io::Write as _;

use common::{
    FaultKind, RunStatus, assert_every_tick_on_disk, disturbance, judge, on_a_noisy_host, outcome,
    plant_stalled, summary,
};
use deltaloop_supervisor::ops::bench_net::{TwoHosts, ip};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::time::Duration;

mod controller_remote;
mod ctrl_c;
mod flood;
mod foreign;
mod plant_remote;
mod wire;

const ROOT: &str = env!("CARGO_MANIFEST_DIR");
const PORT: u16 = 7447;

/// A lossy, slow, jittery emulated link: 50 µs delay, 50 µs jitter, 1 % loss, seed 7.
const LOSSY: &[&str] = &[
    "--link-delay-us",
    "50",
    "--link-jitter-us",
    "50",
    "--link-loss",
    "0.01",
    "--link-seed",
    "7",
];

/// One split run at a time: two realtime loops (four processes, two bridges) on a 2-CPU machine
/// would measure each other.
static ONE_AT_A_TIME: std::sync::Mutex<()> = std::sync::Mutex::new(());

/// Two namespaces, `a` (supervisor, and the plant or the controller) and `b` (the other one), a veth pair between them
/// (10.77.0.1/30 in `a`, 10.77.0.2/30 in `b`), and a folder with each side's iceoryx2 root
/// (`deltaloop bench net`'s [`TwoHosts`]). Dropping it deletes both namespaces (and with them the
/// veth pair), the roots' shared memory, then the folder.
struct Hosts {
    net: TwoHosts,
    tmp: tempfile::TempDir,
}

/// Says on stderr why `test` is skipped if namespaces cannot be made here: not root.
fn not_root(test: &str) -> bool {
    // SAFETY: geteuid has no preconditions.
    let not = unsafe { libc::geteuid() } != 0;
    if not {
        skip(
            test,
            "needs root (ip netns add, a veth pair) to make two hosts on one machine",
        );
    }
    not
}

/// Says on stderr that `test` is skipped and why; with `DELTALOOP_REQUIRE_NETNS=1` (a machine
/// that must run these tests) a skip fails the test instead.
fn skip(test: &str, why: &str) {
    if std::env::var_os("DELTALOOP_REQUIRE_NETNS").is_some_and(|v| v == "1") {
        panic!("{test} cannot run here ({why}) and DELTALOOP_REQUIRE_NETNS=1");
    }
    eprintln!("SKIPPED {test}: {why}");
}

impl Hosts {
    /// None (after saying why on stderr) where namespaces cannot be made here.
    fn new(test: &str) -> Option<(Self, std::sync::MutexGuard<'static, ()>)> {
        if not_root(test) {
            return None;
        }
        let tmp = tempfile::tempdir().unwrap();
        match TwoHosts::new(tmp.path(), false) {
            Ok(net) => Some((
                Hosts { net, tmp },
                ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner()),
            )),
            Err(e) => {
                skip(
                    test,
                    &format!(
                        "cannot make two network namespaces joined by a veth pair (needs root and iproute2 with netns and veth): {e:#}"
                    ),
                );
                None
            }
        }
    }

    fn root(&self, side: &str) -> PathBuf {
        self.net.root(side)
    }

    /// `prog args…` in namespace `side` ("a" or "b") with that side's iceoryx2 root, from the
    /// repository root.
    fn cmd(&self, side: &str, prog: &str, args: &[&str]) -> Command {
        let mut c = self.net.cmd(side, Path::new(prog), args);
        c.current_dir(ROOT);
        c
    }

    /// The link key both sides of every run here hold (made on first use, mode 600).
    fn key(&self) -> String {
        let p = self.tmp.path().join("link.key");
        if !p.exists() {
            deltaloop_bridge::seal::LinkKey::write_new(&p).unwrap();
        }
        p.display().to_string()
    }

    /// `deltaloop join 10.77.0.1:7447 --link-key …` in `b`, in the background.
    fn join(&self, extra: &[&str]) -> Child {
        let key = self.key();
        let mut args = vec![
            "join",
            "10.77.0.1:7447",
            "--wait-s",
            "60",
            "--link-key",
            &key,
        ];
        args.extend_from_slice(extra);
        self.cmd("b", env!("CARGO_BIN_EXE_deltaloop"), &args)
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap()
    }

    /// S1 with room for two "hosts" that share this machine's two CPUs (and whatever else runs
    /// on them): a torque budget of 250 µs and 1000 misses in a row (0.3 s) before the safe stop.
    fn roomy_config(&self) -> String {
        let text = std::fs::read_to_string(Path::new(ROOT).join("configs/s1-nominal.toml"))
            .unwrap()
            .replace("[loop]\n", "[loop]\ntorque_budget_us = 250\n")
            + "\n[faults]\ncontroller_silence_ticks = 1000\n";
        let p = self.tmp.path().join("s1-roomy.toml");
        std::fs::write(&p, text).unwrap();
        p.display().to_string()
    }

    /// `deltaloop run CONFIG --<remote>-remote 10.77.0.1:7447 --out OUT …` in `a`.
    fn run_with(&self, remote: Remote, config: &str, out: &Path, extra: &[&str]) -> Child {
        let ep = format!("10.77.0.1:{PORT}");
        let key = self.key();
        let mut args = vec![
            "run",
            config,
            "--law",
            "tdc",
            remote.flag(),
            &ep,
            "--link-key",
            &key,
            "--out",
            out.to_str().unwrap(),
        ];
        args.extend_from_slice(extra);
        self.cmd("a", env!("CARGO_BIN_EXE_deltaloop"), &args)
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap()
    }

    /// Nothing of a run is left in either side's iceoryx2 root: no node or service file, and no
    /// shared memory under its prefix but iceoryx2's management segment of the root itself.
    fn assert_roots_empty(&self) {
        for side in ["a", "b"] {
            let root = self.root(side);
            let mut files = Vec::new();
            walk(&root, &mut files);
            assert!(
                files.is_empty(),
                "left in the iceoryx2 root of {side}: {files:?}"
            );
            let (_, prefix) = deltaloop_transport::ipc::root_of(root.to_str().unwrap()).unwrap();
            let shm: Vec<String> = std::fs::read_dir("/dev/shm")
                .unwrap()
                .filter_map(|e| e.ok()?.file_name().into_string().ok())
                .filter(|n| n.starts_with(&prefix) && !n.ends_with("global_mgmt"))
                .collect();
            assert!(shm.is_empty(), "left in /dev/shm by side {side}: {shm:?}");
        }
    }
}

/// Which process runs in `b`, across the link from the supervisor in `a`.
#[derive(Clone, Copy, Debug)]
enum Remote {
    Controller,
    Plant,
}

impl Remote {
    /// The flag of `deltaloop run`.
    fn flag(self) -> &'static str {
        match self {
            Remote::Controller => "--controller-remote",
            Remote::Plant => "--plant-remote",
        }
    }

    /// The arguments of `deltaloop join`.
    fn join_args(self) -> &'static [&'static str] {
        match self {
            Remote::Controller => &[],
            Remote::Plant => &["--role", "plant"],
        }
    }
}

fn walk(dir: &Path, files: &mut Vec<PathBuf>) {
    let Ok(rd) = std::fs::read_dir(dir) else {
        return;
    };
    for e in rd.flatten() {
        let p = e.path();
        if p.is_dir() {
            walk(&p, files);
        } else {
            files.push(p);
        }
    }
}

/// Waits until the run in `out` has started its loop (its timing file exists), then `ms` more.
fn wait_for_the_loop(out: &Path, ms: u64) {
    let t0 = std::time::Instant::now();
    while !out.join("tdc.timing.csv").is_file() && t0.elapsed() < Duration::from_secs(60) {
        std::thread::sleep(Duration::from_millis(20));
    }
    std::thread::sleep(Duration::from_millis(ms));
}

fn text(b: &[u8]) -> String {
    String::from_utf8_lossy(b).into_owned()
}

/// Stops process `pid` for 8 ms every 60 ms until told to end (SIGSTOP, SIGCONT).
fn hold_now_and_then(
    pid: u32,
) -> (
    std::sync::Arc<std::sync::atomic::AtomicBool>,
    std::thread::JoinHandle<()>,
) {
    let end = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let stop = end.clone();
    let t = std::thread::spawn(move || {
        while !stop.load(std::sync::atomic::Ordering::Relaxed) {
            std::thread::sleep(Duration::from_millis(60));
            // SAFETY: signalling a child of this test (not yet reaped: `both` waits for it
            // after this thread is told to end... or it has exited, and the signal fails).
            unsafe { libc::kill(pid as i32, libc::SIGSTOP) };
            std::thread::sleep(Duration::from_millis(8));
            unsafe { libc::kill(pid as i32, libc::SIGCONT) };
        }
    });
    (end, t)
}

/// Waits for both halves; panics if either takes longer than `limit`.
fn both(run: Child, join: Child, limit: Duration) -> (Output, Output) {
    let r = common::finish_within(run, limit, "deltaloop run (side a)");
    let j = common::finish_within(join, Duration::from_secs(10), "deltaloop join (side b)");
    (r, j)
}

fn inproc_trace(tmp: &Path) -> Vec<u8> {
    let out = tmp.join("inproc");
    if !out.join("trace.csv").is_file() {
        common::run("configs/s1-nominal.toml", "inproc", &out, &["--law", "tdc"]);
    }
    std::fs::read(out.join("trace.csv")).unwrap()
}

/// A lockstep run across the link (`run_extra` on the plant's side, `join_extra` on the
/// controller's) writes the trace.csv of the inproc run, and leaves nothing in either root.
fn assert_lockstep_identical(h: &Hosts, run_extra: &[&str], join_extra: &[&str]) -> String {
    assert_lockstep_identical_with(h, Remote::Controller, run_extra, join_extra)
}

/// What the far side said of the path: whether the far process took the link's socket (the
/// direct path), from the run's log of the far process (`log`).
fn far_went_direct(log: &str) -> bool {
    log.contains("far side: the controller here took the link's socket")
        || log.contains("far side: the plant here took the link's socket")
}

/// [`assert_lockstep_identical`] with `remote` in `b`.
fn assert_lockstep_identical_with(
    h: &Hosts,
    remote: Remote,
    run_extra: &[&str],
    join_extra: &[&str],
) -> String {
    let out = h.tmp.path().join("remote");
    // A second run of one test goes where the first went (its checks are done).
    let _ = std::fs::remove_dir_all(&out);
    let mut join_args = remote.join_args().to_vec();
    join_args.extend_from_slice(join_extra);
    let join = h.join(&join_args);
    let mut args = vec!["--mode", "lockstep"];
    args.extend_from_slice(run_extra);
    let run = h.run_with(remote, "configs/s1-nominal.toml", &out, &args);
    let (r, j) = both(run, join, Duration::from_secs(180));
    assert!(
        r.status.success(),
        "run: {}{}",
        text(&r.stderr),
        text(&r.stdout)
    );
    assert!(j.status.success(), "join: {}", text(&j.stderr));
    let remote = std::fs::read(out.join("trace.csv")).unwrap();
    assert!(
        remote == inproc_trace(h.tmp.path()),
        "trace.csv across the link ({remote:?} remote, {run_extra:?}, {join_extra:?}) differs from inproc"
    );
    h.assert_roots_empty();
    // The log of the process on the other host, with both bridges' lines.
    ["tdc.controller.log", "tdc.plant.log"]
        .iter()
        .map(|f| std::fs::read_to_string(out.join(f)).unwrap_or_default())
        .collect()
}

/// A realtime run across the link (`extra` on the plant's side; `hold_far`: the far bridge is
/// stopped now and then), which must complete, measure the round trip and replay byte for byte.
fn realtime_across_the_link(name: &str, extra: &[&str], hold_far: bool) {
    realtime_across_the_link_with(name, Remote::Controller, extra, hold_far);
}

/// [`realtime_across_the_link`] with `remote` in `b`.
fn realtime_across_the_link_with(name: &str, remote: Remote, extra: &[&str], hold_far: bool) {
    let Some((h, _one)) = Hosts::new(name) else {
        return;
    };
    let injected = hold_far || !extra.is_empty();
    // Both "hosts" share two vCPUs with whatever else runs (see `common::on_a_noisy_host`).
    on_a_noisy_host(name, |attempt| {
        let out = h.tmp.path().join(format!("remote-{attempt}"));
        let join = h.join(remote.join_args());
        let mut args = vec!["--mode", "realtime"];
        args.extend_from_slice(extra);
        let run = h.run_with(remote, &h.roomy_config(), &out, &args);
        // `ip netns exec` and `deltaloop join` exec, so the join's pid is the far bridge's.
        let holder = hold_far.then(|| hold_now_and_then(join.id()));
        let (r, j) = both(run, join, Duration::from_secs(120));
        if let Some((stop, t)) = holder {
            stop.store(true, std::sync::atomic::Ordering::Relaxed);
            t.join().unwrap();
        }
        // Whatever the host did: a typed status (the exit status agrees), every tick on disk,
        // the round trip and the link's measured, the run replays byte for byte, both roots empty.
        let s = summary(&out);
        let status = assert_every_tick_on_disk(&s, &out, "tdc");
        assert_eq!(
            r.status.success(),
            status.is_physical(),
            "run: {}",
            text(&r.stderr)
        );
        if status == RunStatus::Ok {
            assert!(j.status.success(), "join: {}", text(&j.stderr));
        }
        let t = &s["timing"]["tdc"];
        let p50 = t["round_trip"]["p50_us"].as_f64().unwrap();
        let answered = t["round_trip"]["count"].as_u64().unwrap();
        // A run whose every tick the host kept from an answer (it faulted after the silence
        // window) has no round trip to measure: judged as the timing outcome it is.
        judge(
            disturbance(&s, "tdc"),
            (answered > 0)
                .then_some(())
                .ok_or_else(|| format!("no tick answered: {t}")),
        )?;
        // Measured over the link, on the plant's clock: at least the two datagrams' flight.
        assert!(p50 > 5.0, "round trip p50 {p50} µs: {t}");
        // The link's own round trip: the round trip less the time on the controller's host.
        let link = t["link_rtt"]["p50_us"].as_f64().unwrap();
        assert!(
            link > 5.0 && link < p50,
            "link round trip p50 {link} µs: {t}"
        );
        let report = std::fs::read_to_string(out.join("report.md")).unwrap();
        let who = match remote {
            Remote::Controller => "controller on another host",
            Remote::Plant => "plant on another host",
        };
        assert!(
            report.contains(&format!("{} 10.77.0.1:7447", remote.flag()))
                && report.contains(&format!("{who}, across the link at 10.77.0.1:7447")),
            "{report}"
        );
        if injected {
            // The stops and the losses did happen: some ticks went unanswered in time.
            let misses = t["deadline_misses"].as_u64().unwrap();
            assert!(misses > 0, "{name}: no tick missed its budget: {t}");
        }
        let rep = h
            .cmd(
                "a",
                env!("CARGO_BIN_EXE_deltaloop"),
                &["replay", out.to_str().unwrap()],
            )
            .output()
            .unwrap();
        assert!(rep.status.success(), "replay: {}", text(&rep.stderr));
        assert!(
            text(&rep.stdout).contains("byte for byte"),
            "{}",
            text(&rep.stdout)
        );
        h.assert_roots_empty();
        // What depends on timing: the run completed. The stops and the losses make misses (a stop
        // of 8 ms, 27 ticks in a row), so where they were injected the record counts as disturbed
        // beyond them only for the plant's own stalls or a silence far longer than a stop.
        let disturbed = if injected {
            // An 8 ms hold of the far bridge misses about 27 ticks in a row; a burst well past
            // that means the host held it (or this test's own timer) longer than asked, and a
            // robot held that long mid-motion may be flung into a fault (seen: bursts long
            // enough to drive S1 past its singularity margins at tick 248 and 579).
            let burst = t["max_consecutive_misses"].as_u64().unwrap();
            let longest = if hold_far { 40 } else { 100 };
            plant_stalled(&s, "tdc")
                .or_else(|| (burst > longest).then(|| format!("{burst} ticks missed in a row")))
        } else {
            disturbance(&s, "tdc")
        };
        // …and most ticks were answered in time (a run the host slowed to 72 % misses still
        // completes, with fewer answers: judged, not asserted).
        let completed = (status == RunStatus::Ok)
            .then_some(())
            .ok_or_else(|| format!("{status:?}: {}", text(&r.stderr)))
            .and_then(|()| {
                (answered > 1000)
                    .then_some(())
                    .ok_or_else(|| format!("only {answered} ticks answered: {t}"))
            });
        judge(disturbed, completed)?;
        Ok(())
    });
}

/// The run in `out` ended in a fault of `kind` after the cut (1.5 s into the loop), and every tick
/// up to it is accounted for: the trace holds the header and ticks 0.. the fault tick (and at most
/// `extra` more), each either on disk or counted in `lost_ticks`. A supervisor this machine starved
/// of the CPU loses ticks whose samples went with the process that published them; the run says
/// so, and the test says it on stderr (regression: such a run recorded ticks 0..672 of a fault at
/// 4929 and counted none lost).
fn assert_fault_after_the_cut(out: &Path, kind: FaultKind, extra: u64) {
    let s = summary(out);
    assert_eq!(outcome(&s, "tdc"), (RunStatus::Fault, Some(kind)), "{s}");
    let m = &s["laws"]["tdc"];
    let lost = m["lost_ticks"].as_u64().unwrap();
    let tick = m["fault_at_tick"].as_u64().unwrap();
    // Cut after 1.5 s of ticks (5000) and before the 5.8 s run's end.
    assert!((3000..19_000).contains(&tick), "fault at tick {tick}");
    let rows = std::fs::read_to_string(out.join("trace.csv"))
        .unwrap()
        .lines()
        .count() as u64;
    // A run whose robot diverged first (a host that starved the loop into missing tick after
    // tick) ends its trace at the divergence, by the divergence rule, and keeps the fault after
    // the cut beside it. (Two CI runs failed the check below, 1286 and 2308 rows with none lost
    // for faults at 4943 and 5906, their folders not kept: the law's summary is printed now.)
    if let Some(d) = m["diverged_at_tick"].as_u64().filter(|&d| d < tick) {
        assert_eq!(
            rows + lost,
            d + 2,
            "{rows} rows + {lost} lost: header + ticks 0..=divergence tick {d} (fault at {tick}): {m}"
        );
    } else {
        assert!(
            (tick + 1..=tick + 1 + extra).contains(&(rows + lost)),
            "{rows} rows + {lost} lost: header + ticks 0..fault tick {tick} (+ at most {extra}): {m}"
        );
    }
    if lost > 0 {
        let _ = writeln!(
            std::io::stderr(),
            "NOTE: the supervisor lost {lost} ticks to this machine (counted in lost_ticks)"
        );
    }
}

/// A 5.8 s realtime run with `remote` in `b`, its link taken down 1.5 s into the loop; the run
/// folder and how both halves ended. None (said on stderr) if the machine spoiled every attempt
/// before the cut.
fn cut_the_link_mid_run(
    h: &Hosts,
    remote: Remote,
    test: &str,
) -> Option<(PathBuf, Output, Output)> {
    // The cut must come while the loop runs: an attempt that ended before it is run again if the
    // machine disturbed it (its record says so), and fails the test if it did not.
    on_a_noisy_host(test, |attempt| {
        let out = h.tmp.path().join(format!("remote-{attempt}"));
        let join = h.join(remote.join_args());
        let mut run = h.run_with(
            remote,
            &h.roomy_config(),
            &out,
            &["--mode", "realtime", "--hold-s", "5"],
        );
        wait_for_the_loop(&out, 1500);
        if run.try_wait().unwrap().is_none() {
            ip(&["-n", &h.net.a, "link", "set", &h.net.veth_a, "down"]).unwrap();
            let (r, j) = both(run, join, Duration::from_secs(60));
            return Ok((out, r, j));
        }
        let (r, _) = both(run, join, Duration::from_secs(10));
        let s = summary(&out);
        let status = assert_every_tick_on_disk(&s, &out, "tdc");
        h.assert_roots_empty();
        judge(
            disturbance(&s, "tdc"),
            Err(format!(
                "ended before the cut ({status:?}): {}",
                text(&r.stderr)
            )),
        )?;
        unreachable!("a failed check is an error or a panic")
    })
}
