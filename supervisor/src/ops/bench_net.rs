//! `deltaloop bench net`: the link of a run split over two hosts, measured on one machine. Two
//! network namespaces joined by a veth pair ([`TwoHosts`]), each side with its own iceoryx2 root
//! (`DELTALOOP_IOX2_ROOT`), and in the same invocation
//!   1. a plain UDP ping-pong of state-sized datagrams, one per 300 µs (`deltaloop-bridge ping` /
//!      `pong`), as many round trips as the runs have ticks,
//!   2. realtime S1 + hold (`tdc`) across two hosts (`deltaloop run … --controller-remote` in one
//!      namespace, `deltaloop join` in the other): on the direct path (plant and controller
//!      socket to socket), then on the relay (both bridges blocking); with `--polling` also the
//!      direct path with the controller on the other CPU, blocking and polling, and the relay
//!      with each bridge polling,
//!   3. the same run on one host (no bridge), for reference,
//!   4. with `--zenoh-bridge`: the same ping-pong over Zenoh, TCP and UDP endpoints.
//!
//! The namespaces, the veth pair, each root's shared memory and a temporary output folder are
//! removed when [`TwoHosts`] is dropped: at the end, on an error and after Ctrl-C.

use crate::ops::loopback::{Kid, remove_root};
use anyhow::{Context, Result, bail};
use deltaloop_runner::procs::exe_dir;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::atomic::{AtomicU32, Ordering};
use std::time::Duration;

/// The config of the runs: S1 with the `tdc` law (`--law tdc`), its hold given on the command line.
const S1: &str = include_str!("../../../configs/s1-nominal.toml");
/// Address of the plant's side (`a`) and of the controller's (`b`) on the veth pair.
pub const ADDR_A: &str = "10.77.0.1";
pub const ADDR_B: &str = "10.77.0.2";
/// S1's motion, s, and the loop's period, µs.
const MOTION_S: f64 = 0.8;
const PERIOD_US: f64 = 300.0;

/// Why this machine cannot run the benchmark, if it cannot: root, `ip` (iproute2) and the
/// `deltaloop-bridge` next to this executable.
pub fn missing() -> Option<String> {
    // SAFETY: geteuid has no preconditions.
    if unsafe { libc::geteuid() } != 0 {
        return Some("bench net needs root (ip netns add, a veth pair)".into());
    }
    if Command::new("ip")
        .arg("-V")
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()
        .is_err()
    {
        return Some("bench net needs `ip` (iproute2) on PATH".into());
    }
    match exe_dir() {
        Ok(d) if d.join("deltaloop-bridge").is_file() => None,
        Ok(d) => Some(format!(
            "bench net needs deltaloop-bridge next to deltaloop, in {}",
            d.display()
        )),
        Err(e) => Some(format!("bench net: {e}")),
    }
}

/// `ip ARGS…`; its stderr in the error.
pub fn ip(args: &[&str]) -> Result<()> {
    let o = Command::new("ip")
        .args(args)
        .output()
        .context("cannot run ip")?;
    if !o.status.success() {
        bail!(
            "ip {}: {}",
            args.join(" "),
            String::from_utf8_lossy(&o.stderr).trim()
        );
    }
    Ok(())
}

/// Two namespaces of this machine, `a` (plant and supervisor, [`ADDR_A`]/30) and `b`
/// (controller, [`ADDR_B`]/30), joined by a veth pair, and a folder `dir` holding each side's
/// iceoryx2 root. Dropping it deletes both namespaces (and with them the veth pair), every
/// shared-memory segment under each root's prefix, and `dir` if it was made here.
pub struct TwoHosts {
    pub a: String,
    pub b: String,
    /// The veth end in `a`.
    pub veth_a: String,
    dir: PathBuf,
    remove_dir: bool,
    /// Commands in either namespace see tracefs (`--explain`): `ip netns exec` mounts a sysfs of
    /// the namespace's own over /sys, which hides it; it is mounted again in the command's
    /// private mount namespace.
    pub tracefs: bool,
}

impl TwoHosts {
    /// Makes the namespaces (names unique on this machine: pid and a counter) and the pair; the
    /// roots go in `dir` (made if missing). `remove_dir`: remove `dir` when dropped.
    pub fn new(dir: &Path, remove_dir: bool) -> Result<Self> {
        static N: AtomicU32 = AtomicU32::new(0);
        let id = format!(
            "{}{}",
            std::process::id() % 100_000,
            N.fetch_add(1, Ordering::Relaxed)
        );
        std::fs::create_dir_all(dir).with_context(|| format!("cannot make {}", dir.display()))?;
        let h = TwoHosts {
            a: format!("dlb{id}a"),
            b: format!("dlb{id}b"),
            veth_a: format!("vdl{id}a"),
            dir: dir.canonicalize()?,
            remove_dir,
            tracefs: false,
        };
        let veth_b = format!("vdl{id}b");
        ip(&["netns", "add", &h.a])?;
        ip(&["netns", "add", &h.b])?;
        ip(&[
            "link", "add", &h.veth_a, "netns", &h.a, "type", "veth", "peer", "name", &veth_b,
            "netns", &h.b,
        ])?;
        for (ns, dev, addr) in [(&h.a, &h.veth_a, ADDR_A), (&h.b, &veth_b, ADDR_B)] {
            ip(&["-n", ns, "addr", "add", &format!("{addr}/30"), "dev", dev])?;
            ip(&["-n", ns, "link", "set", dev, "up"])?;
            ip(&["-n", ns, "link", "set", "lo", "up"])?;
        }
        Ok(h)
    }

    /// Side `side`'s ("a" or "b") iceoryx2 root.
    pub fn root(&self, side: &str) -> PathBuf {
        self.dir.join(format!("iox2-{side}"))
    }

    /// `prog args…` in namespace `side` ("a" or "b") with that side's iceoryx2 root. `ip netns
    /// exec` and `env` exec in place: the child's pid is `prog`'s.
    pub fn cmd(&self, side: &str, prog: &Path, args: &[&str]) -> Command {
        let ns = if side == "a" { &self.a } else { &self.b };
        let mut c = Command::new("ip");
        c.args(["netns", "exec", ns]);
        if self.tracefs {
            c.args([
                "sh",
                "-c",
                "[ -d /sys/kernel/tracing/instances ] || mount -t tracefs nodev /sys/kernel/tracing 2>/dev/null; exec \"$@\"",
                "sh",
            ]);
        }
        c.arg("env")
            .arg(format!("DELTALOOP_IOX2_ROOT={}", self.root(side).display()))
            .arg(prog)
            .args(args);
        c
    }

    /// The shared-memory prefix of side `side`'s root (docs/protocol.md §14).
    pub fn shm_prefix(&self, side: &str) -> Option<String> {
        deltaloop_transport::ipc::root_of(self.root(side).to_str()?).map(|(_, p)| p)
    }
}

impl Drop for TwoHosts {
    fn drop(&mut self) {
        let _ = ip(&["netns", "del", &self.a]);
        let _ = ip(&["netns", "del", &self.b]);
        for side in ["a", "b"] {
            remove_root(&self.root(side), false);
        }
        if self.remove_dir {
            let _ = std::fs::remove_dir_all(&self.dir);
        }
    }
}

/// One row of the table: round trip p50 / p99 / p99.9, µs, and the misses (as text).
#[derive(Debug, Clone, PartialEq)]
pub struct Row {
    pub path: String,
    pub p50: f64,
    pub p99: f64,
    pub p999: f64,
    pub misses: String,
    /// Misses ÷ ticks of a run's row (None: a ping-pong).
    pub miss_ratio: Option<f64>,
}

/// The percentiles of a `deltaloop-bridge ping` / `zping` line (`…: N round trips, p50 X µs,
/// p99 Y µs, p99.9 Z µs, max M µs, lost L`); the misses are the lost round trips.
pub fn parse_ping(path: &str, text: &str) -> Option<Row> {
    let line = text.lines().rev().find(|l| l.contains("round trips"))?;
    let field = |key: &str| -> Option<&str> {
        line.split(", ")
            .find_map(|f| f.strip_prefix(key))
            .map(|v| v.trim_end_matches(" µs"))
    };
    let num = |key: &str| field(key)?.parse::<f64>().ok().filter(|x| x.is_finite());
    let n = line.split(": ").nth(1)?.split(' ').next()?;
    Some(Row {
        path: path.into(),
        p50: num("p50 ")?,
        p99: num("p99 ")?,
        p999: num("p99.9 ")?,
        misses: format!("{} lost of {n}", field("lost ")?),
        miss_ratio: None,
    })
}

/// The row of a run folder's `summary.json` (law `tdc`).
fn run_row(path: &str, out: &Path) -> Result<Row> {
    let f = out.join("summary.json");
    let s: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(&f).with_context(|| format!("cannot read {}", f.display()))?,
    )?;
    let t = &s["timing"]["tdc"];
    let rt = &t["round_trip"];
    let num = |v: &serde_json::Value| v.as_f64().filter(|x| x.is_finite());
    let (Some(p50), Some(p99), Some(p999)) =
        (num(&rt["p50_us"]), num(&rt["p99_us"]), num(&rt["p999_us"]))
    else {
        bail!("{}: no round trip of tdc", f.display());
    };
    let status = s["laws"]["tdc"]["status"].as_str().unwrap_or("?");
    Ok(Row {
        path: path.into(),
        p50,
        p99,
        p999,
        misses: format!(
            "{} of {} ticks ({status}){}",
            t["deadline_misses"],
            t["ticks"],
            causes(t)
        ),
        miss_ratio: match (t["deadline_misses"].as_f64(), t["ticks"].as_f64()) {
            (Some(m), Some(n)) if n > 0.0 => Some(m / n),
            _ => None,
        },
    })
}

/// `; preempted 3, link 10 (culprits: …)`: a run's missed ticks by cause (`--explain`), or
/// nothing.
fn causes(t: &serde_json::Value) -> String {
    let Some(m) = t["miss_causes"].as_object() else {
        return String::new();
    };
    let mut by: Vec<(&String, u64)> = m
        .iter()
        .filter_map(|(c, n)| Some((c, n.as_u64().filter(|&n| n > 0)?)))
        .collect();
    by.sort_by(|a, b| b.1.cmp(&a.1).then(a.0.cmp(b.0)));
    let mut s: Vec<String> = by.iter().map(|(c, n)| format!("{c} {n}")).collect();
    if s.is_empty() {
        s.push("no miss".into());
    }
    let culprits: Vec<String> = t["miss_culprits"]
        .as_object()
        .map(|m| m.iter().map(|(c, n)| format!("{c} {n}")).collect())
        .unwrap_or_default();
    let culprits = if culprits.is_empty() {
        String::new()
    } else {
        format!(" (culprits: {})", culprits.join(", "))
    };
    format!("; by cause: {}{culprits}", s.join(", "))
}

/// The last lines of a log, for an error.
fn tail(log: &Path) -> String {
    let text = std::fs::read_to_string(log).unwrap_or_default();
    let lines: Vec<&str> = text.lines().collect();
    lines[lines.len().saturating_sub(5)..].join("\n")
}

/// Runs the benchmark (see the module) and prints the table; the last line is
/// [`summary_line`].
/// `out`: where the runs' folders go (None: a temporary folder, removed at the end).
/// A run argument of the bench's own: this row's config has both loop processes polling.
const POLLING: &str = "<polling>";

/// How long a polling bridge polls for the reply, µs (the 150 µs budget: a reply later than that
/// is late anyway).
const POLL_US: u32 = 150;

/// `deltaloop bench net`; `polling` adds the runs with the far, then the near bridge polling;
/// `explain` names each run's misses' causes (`--explain`).
pub fn run(
    hold_s: f64,
    out: Option<&Path>,
    zenoh_bridge: Option<&Path>,
    polling: bool,
    explain: bool,
) -> Result<()> {
    if let Some(why) = missing() {
        bail!("{why}");
    }
    let (dir, remove) = match out {
        Some(d) => (d.to_path_buf(), false),
        None => (
            std::env::temp_dir().join(format!("deltaloop-bench-net-{}", std::process::id())),
            true,
        ),
    };
    let mut h = TwoHosts::new(&dir, remove)?;
    h.tracefs = explain;
    let b = Bench::new(h, hold_s, explain)?;
    println!(
        "deltaloop bench net: two network namespaces joined by veth ({ADDR_A} | {ADDR_B}), S1 + {hold_s} s hold (tdc, realtime, 1000-tick hold window), {} UDP round trips; folders in {}",
        b.count,
        if remove {
            "a temporary folder".to_string()
        } else {
            b.h.dir.display().to_string()
        }
    );
    // 1, 4: the ping-pongs.
    let mut rows = vec![b.ping(
        &b.bridge,
        "pong",
        "ping",
        &format!("{ADDR_B}:7500"),
        "UDP ping-pong, veth",
    )?];
    if let Some(z) = zenoh_bridge {
        for (ep, label) in [
            (format!("tcp/{ADDR_B}:7600"), "Zenoh ping-pong, TCP"),
            (format!("udp/{ADDR_B}:7601"), "Zenoh ping-pong, UDP"),
        ] {
            rows.push(b.ping(z, "zpong", "zping", &ep, label)?);
        }
    }
    // 2: across the link: the direct path (plant and controller socket to socket), then the
    // relay through both bridges (blocking; with `polling`, also each bridge polling).
    let direct = rows.len();
    rows.push(b.across(
        "direct",
        "direct (plant and controller socket to socket)",
        &[],
        &["--link-path=direct"],
    )?);
    let relay = rows.len();
    rows.push(b.across(
        "bridge",
        "relay (both bridges blocking)",
        &[],
        &["--link-path=relay"],
    )?);
    if polling {
        let spin = format!("{POLL_US}");
        // The direct path with the controller on the other CPU (as on two hosts, where each
        // has its own), blocking, then both processes polling before they block.
        rows.push(b.across(
            "direct-split",
            "direct, controller on CPU 0 (join --cpu 0), blocking",
            &["--cpu", "0"],
            &["--link-path=direct"],
        )?);
        rows.push(b.across(
            "direct-polling",
            &format!(
                "direct, controller on CPU 0, both polling {POLL_US} µs ([loop.realtime] spin_us)"
            ),
            &["--cpu", "0"],
            &["--link-path=direct", POLLING],
        )?);
        rows.push(b.across(
            "bridge-far-polling",
            &format!("relay, far bridge polling (join --spin-us {POLL_US})"),
            &["--spin-us", &spin],
            &["--link-path=relay"],
        )?);
        rows.push(b.across(
            "bridge-near-polling",
            &format!("relay, near bridge polling (--link-spin-us {POLL_US})"),
            &[],
            &["--link-path=relay", &format!("--link-spin-us={POLL_US}")],
        )?);
    }
    // 3: one host.
    rows.push(b.one_host()?);
    println!("{}", table(&rows));
    println!("{}", summary_line(&rows, direct, relay));
    Ok(())
}

/// The last line: `udp_p50_us=… direct_p50_us=… bridge_p50_us=… one_host_p50_us=…
/// bridge_over_udp=… direct_over_udp=… direct_miss_ratio=… one_host_miss_ratio=…` (the ratios
/// misses ÷ ticks; `bridge` is the relay path).
pub fn summary_line(rows: &[Row], direct: usize, relay: usize) -> String {
    let (udp, one) = (&rows[0], &rows[rows.len() - 1]);
    let (d, r) = (&rows[direct], &rows[relay]);
    let ratio = |r: &Row| r.miss_ratio.map_or("na".into(), |x| format!("{x:.1e}"));
    format!(
        "udp_p50_us={:.1} direct_p50_us={:.1} bridge_p50_us={:.1} one_host_p50_us={:.1} bridge_over_udp={:.2} direct_over_udp={:.2} direct_miss_ratio={} one_host_miss_ratio={}",
        udp.p50,
        d.p50,
        r.p50,
        one.p50,
        r.p50 / udp.p50,
        d.p50 / udp.p50,
        ratio(d),
        ratio(one)
    )
}

/// One `bench net`: the two hosts, the programs, the S1 config and the link key every row uses.
struct Bench {
    h: TwoHosts,
    deltaloop: PathBuf,
    bridge: PathBuf,
    config: String,
    /// The same, both loop processes polling [`POLL_US`] before they block (`--polling`).
    config_polling: String,
    hold: String,
    /// UDP round trips of a ping-pong.
    count: u32,
    /// How long any one program may take.
    wait: Duration,
    key: String,
    endpoint: String,
}

impl Bench {
    fn new(h: TwoHosts, hold_s: f64, explain: bool) -> Result<Self> {
        let dir = h.dir.clone();
        let bin = exe_dir()?;
        let config = dir.join("s1-nominal.toml");
        // A hold window of 1000 ticks (300 ms) instead of S1's 100: a link whose first ticks come
        // slower than the 150 µs budget (the far side's first wake-ups, its caches cold) ended
        // about one bench run in three in a fault before a round trip was measured; the misses
        // still count.
        let record = if explain {
            "[record]\nexplain = true\n"
        } else {
            ""
        };
        std::fs::write(
            &config,
            format!("{S1}\n[faults]\ncontroller_silence_ticks = 1000\n{record}"),
        )?;
        let polling = dir.join("s1-polling.toml");
        std::fs::write(
            &polling,
            format!(
                "{S1}\n[faults]\ncontroller_silence_ticks = 1000\n[loop.realtime]\nspin_us = {POLL_US}\n{record}"
            ),
        )?;
        // Both sides of every run across the link hold this key (the link has no
        // unauthenticated mode: the bench measures it sealed).
        let key_file = dir.join("link.key");
        deltaloop_link_setup::LinkKey::write_new(&key_file).map_err(anyhow::Error::msg)?;
        Ok(Self {
            h,
            deltaloop: bin.join("deltaloop"),
            bridge: bin.join("deltaloop-bridge"),
            config: config.display().to_string(),
            config_polling: polling.display().to_string(),
            hold: format!("{hold_s}"),
            count: ((MOTION_S + hold_s) * 1e6 / PERIOD_US).round().max(1000.0) as u32,
            wait: Duration::from_secs_f64(120.0 + 3.0 * hold_s),
            key: key_file.display().to_string(),
            endpoint: format!("{ADDR_A}:7447"),
        })
    }

    /// A ping-pong: `prog serve` on host b, `prog call` on host a, `count` round trips.
    fn ping(&self, prog: &Path, serve: &str, call: &str, ep: &str, label: &str) -> Result<Row> {
        let dir = &self.h.dir;
        let name: String = label.chars().filter(char::is_ascii_alphanumeric).collect();
        let log = dir.join(format!("{serve}-{name}.log"));
        let mut pong = Kid::spawn(
            self.h.cmd("b", prog, &[serve, "--listen", ep]),
            "pong",
            &log,
        )?;
        std::thread::sleep(Duration::from_millis(if serve == "pong" {
            300
        } else {
            1000
        }));
        let plog = dir.join(format!("{call}-{name}.log"));
        let count = self.count.to_string();
        let cmd = self
            .h
            .cmd("a", prog, &[call, "--connect", ep, "--count", &count]);
        let st = Kid::spawn(cmd, "ping", &plog)?.wait(self.wait, dir)?;
        pong.signal(libc::SIGTERM);
        let _ = pong.wait(Duration::from_secs(5), dir);
        let text = std::fs::read_to_string(&plog).unwrap_or_default();
        match parse_ping(label, &text) {
            Some(r) if st.success() => Ok(r),
            _ => bail!("{call} failed ({st}): {}", tail(&plog)),
        }
    }

    /// `deltaloop run …` of S1 in realtime into `out`, and `extra`.
    fn run_args(&self, out: &Path, extra: &[String]) -> Vec<String> {
        let polling = extra.iter().any(|a| a == POLLING);
        let extra: Vec<String> = extra.iter().filter(|a| *a != POLLING).cloned().collect();
        let mut args: Vec<String> = [
            "run",
            if polling {
                &self.config_polling
            } else {
                &self.config
            },
            "--law",
            "tdc",
            "--mode",
            "realtime",
            "--hold-s",
            &self.hold,
            "--out",
            out.to_str().unwrap_or_default(),
        ]
        .map(String::from)
        .to_vec();
        args.extend(extra);
        args
    }

    /// A run with its controller on host b (`join`), the supervisor on host a.
    fn across(
        &self,
        name: &str,
        label: &str,
        join_extra: &[&str],
        run_extra: &[&str],
    ) -> Result<Row> {
        let dir = &self.h.dir;
        let remote = dir.join(name);
        let mut jargs = vec![
            "join",
            &self.endpoint,
            "--wait-s",
            "60",
            "--link-key",
            &self.key,
        ];
        jargs.extend_from_slice(join_extra);
        let mut join = Kid::spawn(
            self.h.cmd("b", &self.deltaloop, &jargs),
            "deltaloop join",
            &dir.join(format!("join-{name}.log")),
        )?;
        let mut extra = vec![
            "--controller-remote".to_string(),
            self.endpoint.clone(),
            "--link-key".into(),
            self.key.clone(),
        ];
        extra.extend(run_extra.iter().map(|a| a.to_string()));
        let args = self.run_args(&remote, &extra);
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        let log = dir.join(format!("run-{name}.log"));
        Kid::spawn(
            self.h.cmd("a", &self.deltaloop, &args),
            "deltaloop run",
            &log,
        )?
        .wait(self.wait, &remote)?;
        let _ = join.wait(Duration::from_secs(10), &remote);
        run_row(label, &remote).with_context(|| format!("the run {label}: {}", tail(&log)))
    }

    /// The same run on one host, no bridge.
    fn one_host(&self) -> Result<Row> {
        let local = self.h.dir.join("one-host");
        let args = self.run_args(&local, &[]);
        let log = self.h.dir.join("run-one-host.log");
        let mut c = Command::new(&self.deltaloop);
        c.args(&args);
        Kid::spawn(c, "deltaloop run", &log)?.wait(self.wait, &local)?;
        run_row("one host, no bridge", &local)
            .with_context(|| format!("the run on one host: {}", tail(&log)))
    }
}

/// The table, Markdown.
pub fn table(rows: &[Row]) -> String {
    let mut t =
        String::from("| path | round trip p50 / p99 / p99.9 (µs) | misses |\n|---|---|---|");
    for r in rows {
        t += &format!(
            "\n| {} | {:.1} / {:.1} / {:.1} | {} |",
            r.path, r.p50, r.p99, r.p999, r.misses
        );
    }
    t
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_ping_line_gives_its_row() {
        let r = parse_ping(
            "udp",
            "noise\nudp ping-pong 10.77.0.2:7500: 33000 round trips, p50 15.9 µs, p99 47.5 µs, p99.9 230.0 µs, max 2520.1 µs, lost 2\n",
        )
        .unwrap();
        assert_eq!((r.p50, r.p99, r.p999), (15.9, 47.5, 230.0));
        assert_eq!(r.misses, "2 lost of 33000");
        assert!(parse_ping("udp", "no line").is_none());
        let t = table(&[r]);
        assert!(
            t.ends_with("| udp | 15.9 / 47.5 / 230.0 | 2 lost of 33000 |"),
            "{t}"
        );
    }
}
