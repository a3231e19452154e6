//! `deltaloop top` end to end in a tmux pane, and `deltaloop soak` interrupted by SIGINT.

use crate::common;

use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

const BIN: &str = env!("CARGO_BIN_EXE_deltaloop");
const ROOT: &str = env!("CARGO_MANIFEST_DIR");

/// Installs tmux with apt-get, as the Python tests install their venv: only where that works
/// without asking (root, apt-get present, no standard input); otherwise the caller's assertion
/// says what to install.
fn install_tmux() {
    // SAFETY: geteuid has no preconditions.
    if unsafe { libc::geteuid() } != 0 || Command::new("apt-get").arg("--version").output().is_err()
    {
        return;
    }
    for args in [
        &["update", "-qq"][..],
        &["install", "-y", "-qq", "tmux"][..],
    ] {
        let _ = Command::new("apt-get")
            .args(args)
            .env("DEBIAN_FRONTEND", "noninteractive")
            .stdin(std::process::Stdio::null())
            .output();
    }
}

/// A private tmux server (its own socket), killed when dropped.
struct Tmux {
    socket: String,
}

impl Tmux {
    fn new() -> Self {
        let has_tmux = || {
            Command::new("tmux")
                .arg("-V")
                .output()
                .is_ok_and(|o| o.status.success())
        };
        if !has_tmux() {
            install_tmux();
        }
        assert!(
            has_tmux(),
            "tmux is not installed and could not be installed here: this test drives `deltaloop top` in a tmux pane; install it (apt-get install tmux)"
        );
        Self {
            socket: format!("deltaloop-top-test-{}", std::process::id()),
        }
    }

    fn cmd(&self, args: &[&str]) -> String {
        let o = Command::new("tmux")
            .args(["-L", &self.socket])
            .args(args)
            .output()
            .expect("tmux runs");
        assert!(
            o.status.success(),
            "tmux {args:?}: {}",
            String::from_utf8_lossy(&o.stderr)
        );
        String::from_utf8_lossy(&o.stdout).into_owned()
    }

    fn screen(&self) -> String {
        self.cmd(&["capture-pane", "-p", "-t", "top"])
    }

    /// Polls the pane until `ok` holds, for at most `secs`.
    fn wait_for(&self, secs: u64, what: &str, ok: impl Fn(&str) -> bool) -> String {
        let end = Instant::now() + Duration::from_secs(secs);
        loop {
            let s = self.screen();
            if ok(&s) {
                return s;
            }
            assert!(
                Instant::now() < end,
                "{what} within {secs} s; the pane:\n{s}"
            );
            std::thread::sleep(Duration::from_millis(100));
        }
    }
}

impl Drop for Tmux {
    fn drop(&mut self) {
        let _ = Command::new("tmux")
            .args(["-L", &self.socket, "kill-server"])
            .output();
    }
}

/// The tick count on the screen (`ticks    48020 / 136001 (35.3 %)`).
fn ticks_on(screen: &str) -> Option<u64> {
    let line = screen
        .lines()
        .map(|l| l.trim_start_matches('│'))
        .find(|l| l.starts_with("ticks "))?;
    let after = line.strip_prefix("ticks")?;
    after.split_whitespace().next()?.parse().ok()
}

/// The four numbers of a percentile row (`round trip  3.7  163.2  6857  13631  (30824 ticks)`).
fn row(screen: &str, name: &str) -> Option<Vec<f64>> {
    let line = screen.lines().find(|l| l.contains(name))?;
    let rest = line.split(name).nth(1)?;
    let v: Vec<f64> = rest
        .split_whitespace()
        .take(4)
        .map_while(|w| w.parse().ok())
        .collect();
    (v.len() == 4).then_some(v)
}

/// `top RUN_ID` in a 100×30 tmux pane watches a lockstep run: the run id, a growing tick count,
/// round-trip percentiles and the tracking error show; `q` quits top at once; the run goes on,
/// completes with every tick, and its trace is reproduced byte for byte in-process (top changed
/// nothing in the data).
#[test]
fn top_watches_a_lockstep_run_in_tmux_and_q_leaves_it_undisturbed() {
    let tmux = Tmux::new();
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("run");
    // 20 s of hold after S1 (≈ 69 000 ticks); a 100 µs compute delay paces lockstep to at most
    // 10 kHz on any machine (lockstep results do not depend on it), so the run lasts ≥ 7 s.
    let mut run = Command::new(BIN)
        .args(["run", "configs/s1-nominal.toml", "--mode", "lockstep"])
        .args([
            "--law",
            "tdc",
            "--hold-s",
            "20",
            "--compute-delay-us",
            "100",
        ])
        .arg("--out")
        .arg(&out)
        .current_dir(ROOT)
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let rid = common::run_id_of(&out, &mut run);
    let top = format!("{BIN} top {rid}; echo top-exit=$?; sleep 60");
    tmux.cmd(&[
        "new-session",
        "-d",
        "-s",
        "top",
        "-x",
        "100",
        "-y",
        "30",
        &top,
    ]);
    let first = tmux.wait_for(10, "top shows the run's ticks and round trip", |s| {
        s.contains(&format!("run {rid}"))
            && ticks_on(s).is_some_and(|t| t > 0)
            && row(s, "round trip").is_some()
    });
    let t1 = ticks_on(&first).unwrap();
    let second = tmux.wait_for(5, "the tick count grows", |s| {
        ticks_on(s).is_some_and(|t| t > t1)
    });
    assert!(
        second.contains("law tdc") && second.contains("mode lockstep"),
        "{second}"
    );
    assert!(second.contains("status   running"), "{second}");
    let rt = row(&second, "round trip").unwrap();
    assert!(
        rt[0] > 0.0 && rt.windows(2).all(|w| w[0] <= w[1]),
        "p50 ≤ p99 ≤ p99.9 ≤ max: {rt:?}\n{second}"
    );
    let err = second
        .lines()
        .find(|l| l.contains("RMS since tick"))
        .unwrap_or_else(|| panic!("no tracking error:\n{second}"));
    let rms: Vec<f64> = err
        .split_whitespace()
        .filter_map(|w| w.parse::<f64>().ok())
        .skip(1)
        .collect();
    assert!(
        rms.len() == 3 && rms.iter().all(|e| e.is_finite() && *e < 1e-3),
        "{err}"
    );
    assert!(second.contains("wake lateness") && second.contains("no deadline in lockstep"));

    // One spare slot: a second observer is refused, saying why.
    let second = common::deltaloop(&["top", "--plain", &rid]);
    let said = String::from_utf8_lossy(&second.stderr);
    assert!(
        !second.status.success() && said.contains("spare observer slot"),
        "{said}"
    );

    assert!(
        run.try_wait().unwrap().is_none(),
        "the run must still be going"
    );
    tmux.cmd(&["send-keys", "-t", "top", "q"]);
    tmux.wait_for(3, "top quits on q", |s| s.contains("top-exit=0"));
    assert!(
        run.try_wait().unwrap().is_none(),
        "the run must outlive top's exit"
    );

    // The slot is free again: `top --plain` attaches, and ends by itself with the run.
    let plain = Command::new(BIN)
        .args(["top", "--plain", "--interval", "200ms", &rid])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let status = run.wait().unwrap();
    let plain = plain.wait_with_output().unwrap();
    let lines = String::from_utf8_lossy(&plain.stdout).into_owned();
    assert!(
        plain.status.success(),
        "{lines}{}",
        String::from_utf8_lossy(&plain.stderr)
    );
    let last = lines.lines().last().unwrap_or_default().to_string();
    let mut stderr = String::new();
    std::io::Read::read_to_string(run.stderr.as_mut().unwrap(), &mut stderr).unwrap();
    assert!(status.success(), "the run failed: {stderr}");
    let summary = common::summary(&out);
    common::assert_complete_and_kept(&summary, &out, "tdc");
    let n = summary["laws"]["tdc"]["ticks"].as_u64().unwrap();
    assert!(
        last.contains(&format!("status=completed ticks={} misses=0 ", n + 1)),
        "{last}"
    );
    common::assert_clean(&out, &summary);
    let replay = common::deltaloop(&["replay", out.to_str().unwrap()]);
    assert!(
        replay.status.success(),
        "{}",
        String::from_utf8_lossy(&replay.stderr)
    );
}

/// A realtime soak stopped by SIGINT after a few seconds leaves every tick it ran on disk: the
/// trace and timing rows of ticks 0..K (K = where it stopped), no tick or sample lost, the timing
/// counting exactly those ticks, and a last (partial) minute summary that counts them too. Every
/// tick on disk holds whatever the host does; that the soak was still running when SIGINT came,
/// with nothing lost, is judged by its record (a host that stalls the loop into a fault first says
/// nothing about SIGINT: run again, inconclusive after three).
#[test]
fn soak_interrupted_by_sigint_keeps_every_tick() {
    common::on_a_noisy_host("soak_interrupted_by_sigint", |_| soak_interrupted_once());
}

fn soak_interrupted_once() -> Result<(), String> {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("soak");
    let child = Command::new(BIN)
        .args(["soak", "configs/soak.toml", "--duration", "10s", "--out"])
        .arg(&out)
        .current_dir(ROOT)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    // Wait for ≈ 1.3 s of loop in the timing file (≈ 100 B a row, written as ticks finish),
    // then Ctrl-C.
    let timing = out.join("tdc-is-sta.timing.csv");
    let end = Instant::now() + Duration::from_secs(20);
    while std::fs::metadata(&timing).map_or(0, |m| m.len()) < 400_000 {
        assert!(Instant::now() < end, "the soak never got going");
        std::thread::sleep(Duration::from_millis(50));
    }
    // SAFETY: signalling our own child.
    unsafe { libc::kill(child.id() as i32, libc::SIGINT) };
    let o = child.wait_with_output().unwrap();
    let (stdout, stderr) = (
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr),
    );
    let s = common::summary(&out);
    let law = "tdc-is-sta";
    let status = common::assert_every_tick_on_disk(&s, &out, law);
    let (m, t) = (&s["laws"][law], &s["timing"][law]);
    let lost: u64 = ["state", "torque", "telemetry"]
        .iter()
        .map(|k| t["supervisor_lost_samples"][k].as_u64().unwrap_or(0))
        .sum::<u64>()
        + m["lost_ticks"].as_u64().unwrap_or(0);
    let check =
        if status == common::RunStatus::Interrupted && o.status.code() == Some(130) && lost == 0 {
            Ok(())
        } else {
            Err(format!(
                "{status:?}, exit {:?}, {lost} lost: {stderr}",
                o.status.code()
            ))
        };
    common::judge(common::disturbance(&s, law), check)?;
    assert!(
        stderr.contains("interrupted") && stderr.contains("SIGINT"),
        "{stderr}"
    );
    let k = m["interrupted_at_tick"]
        .as_u64()
        .unwrap_or_else(|| panic!("{m}"));
    assert!(k > 3000 && k < 33_334, "stopped at tick {k}");
    assert_eq!(t["ticks"], k, "the timing counts the ticks that ran: {t}");
    let f = std::fs::File::open(out.join("trace.csv")).unwrap();
    let lines = std::io::BufRead::lines(std::io::BufReader::new(f)).count() as u64;
    assert_eq!(lines, k + 1, "header + ticks 0..{k}");
    // The timing rows: ticks 0..K of the loop in order, then the plant's safe stop after STOP.
    let mut rows = csv::Reader::from_path(out.join("tdc-is-sta.timing.csv")).unwrap();
    let ks: Vec<u64> = rows
        .records()
        .map(|r| r.unwrap()[0].parse().unwrap())
        .collect();
    assert!(
        ks.len() as u64 > k,
        "{} timing rows, stopped at {k}",
        ks.len()
    );
    assert!(
        ks[..k as usize].iter().copied().eq(0..k),
        "timing rows 0..{k}"
    );
    // The per-minute summary counts the same ticks.
    let minute = stdout
        .lines()
        .find(|l| l.starts_with("minute 1 (0:00–"))
        .unwrap_or_else(|| panic!("no minute summary: {stdout}\n{stderr}"));
    assert!(
        minute.contains(&format!("partial): {k} ticks, ")),
        "{minute} (stopped at {k})"
    );
    assert!(minute.contains("round trip p50 ") && minute.contains("RSS MiB supervisor "));
    Ok(())
}
