//! `deltaloop soak CONFIG --duration 2h`: the loop for as long as asked. The scenario's motion
//! runs once and the end point is held for the rest of the duration (`scenario.hold_s`), through
//! the normal run path: the run folder, its trace, timing files and histograms are those of
//! `deltaloop run`, streamed to disk as ticks finish (memory does not grow), and Ctrl-C leaves
//! every tick so far on disk. On top of that soak shows a progress line and prints a summary per
//! minute of loop time (ticks, misses, round-trip percentiles of that minute, the RSS of the three
//! processes), fed through [`run::RunRequest::on_tick`] by the run's own observer: the run's spare observer
//! slot stays free for `deltaloop top`.

use crate::ops::run::{self, Overrides};
use anyhow::{Result, bail};
use deltaloop_config::{LoopMode, RecordSection};
use deltaloop_study::record::RunStatus;
use deltaloop_timing::{PeakRss, Percentiles, Seen};
use deltaloop_transport::wire;
use hdrhistogram::Histogram;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

/// The longest soak: the longest hold the config allows (a day).
pub const MAX_DURATION: Duration = Duration::from_secs(deltaloop_config::MAX_HOLD_S as u64);

/// Parses a duration such as `90s`, `10m`, `2h`, `1h30m` (humantime); 1 s ..= 24 h.
pub fn parse_duration(s: &str) -> Result<Duration, String> {
    let d = humantime::parse_duration(s.trim()).map_err(|e| {
        format!("`{s}` is not a duration ({e}): expected e.g. 90s, 10m, 2h or 1h30m")
    })?;
    if d < Duration::from_secs(1) || d > MAX_DURATION {
        return Err(format!("`{s}` is out of range: a soak lasts 1s ..= 24h"));
    }
    Ok(d)
}

/// Disk `trace.csv` takes per tick, bytes: ≈ 630 B (measured on a lockstep S1 run of 202 668
/// ticks), rounded up.
pub const TRACE_BYTES_PER_TICK: u64 = 640;

/// Disk `<law>.timing.csv` takes per tick, bytes: ≈ 106 B (same run), rounded up.
pub const TIMING_BYTES_PER_TICK: u64 = 110;

/// Disk the kernel's record of `--explain` takes per tick while a law runs, bytes: ≈ 25 000
/// events a second of about 135 B each on the default layout's loop CPU at 3.3 kHz (a realtime
/// S1 run: 3.5 MB over 2668 ticks, START and the end included), rounded up. It is removed
/// when the law's misses are explained.
pub const EXPLAIN_BYTES_PER_TICK: u64 = 1100;

/// Disk a run with `record` writes per tick, bytes, and the files that take it.
pub fn per_tick_disk(record: &RecordSection) -> (u64, String) {
    let files: Vec<(u64, &str)> = [
        (record.trace, TRACE_BYTES_PER_TICK, "trace.csv"),
        (record.timing_csv, TIMING_BYTES_PER_TICK, "timing.csv"),
        (
            record.explain,
            EXPLAIN_BYTES_PER_TICK,
            "the kernel's record of --explain (kept until the law ends)",
        ),
    ]
    .into_iter()
    .filter_map(|(on, b, f)| on.then_some((b, f)))
    .collect();
    if files.is_empty() {
        return (0, "no per-tick file".into());
    }
    let names: Vec<&str> = files.iter().map(|f| f.1).collect();
    (files.iter().map(|f| f.0).sum(), names.join(" and "))
}

/// Free bytes of the file system that holds `path` (or its nearest existing ancestor).
fn free_bytes(path: &Path) -> Option<u64> {
    let abs = std::path::absolute(path).ok()?;
    let dir = abs.ancestors().find(|p| p.exists())?;
    let c = std::ffi::CString::new(dir.as_os_str().as_encoded_bytes()).ok()?;
    // SAFETY: statvfs writes into the struct we own; the path is a valid C string.
    let mut st: libc::statvfs = unsafe { std::mem::zeroed() };
    if unsafe { libc::statvfs(c.as_ptr(), &mut st) } != 0 {
        return None;
    }
    Some(st.f_bavail as u64 * st.f_frsize as u64)
}

/// What a run asks of the disk, in the words of its refusal: `asked` names the run and its
/// length as given (`--duration 1day`), `shorter` what to shorten (`--duration`).
pub struct DiskAsk<'a> {
    pub asked: &'a str,
    pub shorter: &'a str,
}

/// Err with one line if a run of `ticks` ticks (of every law) recording what `record` asks
/// would not fit in `free` bytes.
pub fn check_disk(
    ticks: u64,
    record: &RecordSection,
    free: u64,
    dir: &Path,
    ask: &DiskAsk<'_>,
) -> Result<(), String> {
    let (per_tick, files) = per_tick_disk(record);
    let need = ticks.saturating_mul(per_tick);
    if need <= free {
        return Ok(());
    }
    let gb = |b: u64| b as f64 / 1e9;
    Err(format!(
        "{} writes about {:.1} GB ({ticks} ticks of ≈ {per_tick} B in {files}) but {} has {:.1} GB free: choose a shorter {}, another --out, or fewer per-tick files ([record] in the config)",
        ask.asked,
        gb(need),
        dir.display(),
        gb(free),
        ask.shorter
    ))
}

/// Refuses, before anything is written, a run of `ticks` ticks that would not fit on the file
/// system of `dir` (or of its nearest existing ancestor); see [`check_disk`].
pub fn refuse_if_too_big(
    ticks: u64,
    record: &RecordSection,
    dir: &Path,
    ask: &DiskAsk<'_>,
) -> anyhow::Result<()> {
    match free_bytes(dir) {
        Some(free) => check_disk(ticks, record, free, dir, ask).map_err(|e| anyhow::anyhow!(e)),
        None => Ok(()),
    }
}

/// One minute of loop time: the ticks at loop times in ((index − 1)·60 s, index·60 s], and tick 0
/// (t = 0) in the first. Closed at its end, so a run of whole minutes (ticks 0 ..= N, N·Ts a
/// whole number of minutes) ends with a whole minute, not with a lone tick.
#[derive(Clone, Debug, PartialEq)]
pub struct Minute {
    /// 1-based.
    pub index: u64,
    /// Ticks of the loop seen in this minute (with telemetry).
    pub ticks: u64,
    /// Ticks the plant marked missed.
    pub misses: u64,
    /// Round trip of this minute's ticks, µs.
    pub round_trip: Percentiles,
    /// Loop time this minute covers, s (60 but for the last one).
    pub span_s: f64,
}

/// Per-minute accounting of a run's finished ticks, in fixed memory (one histogram reused).
pub struct MinuteAcc {
    ticks_per_minute: u64,
    ts_s: f64,
    minute: u64,
    ticks: u64,
    misses: u64,
    /// The current minute holds a tick.
    open: bool,
    last_k: u64,
    round_trip: Histogram<u64>,
    /// Ticks and misses of the whole run so far.
    pub total_ticks: u64,
    pub total_misses: u64,
    /// Finished minutes not yet printed.
    pub done: Vec<Minute>,
}

impl MinuteAcc {
    /// For a loop of period `ts_s` (s).
    pub fn new(ts_s: f64) -> Self {
        Self {
            ticks_per_minute: (60.0 / ts_s).round().max(1.0) as u64,
            ts_s,
            minute: 0,
            ticks: 0,
            misses: 0,
            open: false,
            last_k: 0,
            round_trip: deltaloop_timing::latency_histogram(),
            total_ticks: 0,
            total_misses: 0,
            done: Vec::new(),
        }
    }

    /// Adds a finished tick; ticks without loop telemetry (the state after the run, a safe stop)
    /// are not part of the loop.
    pub fn push(&mut self, seen: &Seen) {
        let Some(m) = seen.tel.filter(|m| m.flags & wire::TEL_SAFE_STOP == 0) else {
            return;
        };
        let minute = seen.k.saturating_sub(1) / self.ticks_per_minute;
        if minute != self.minute && self.open {
            self.close();
        }
        self.minute = minute;
        self.open = true;
        self.last_k = seen.k;
        self.ticks += 1;
        self.total_ticks += 1;
        if m.flags & wire::TEL_MISSED != 0 {
            self.misses += 1;
            self.total_misses += 1;
        } else if let Some(rt) = deltaloop_timing::round_trip_ns(&m) {
            self.round_trip.saturating_record(rt.max(1));
        }
    }

    /// Ends the current minute (at the end of the run: a partial one), if it holds any tick.
    pub fn close(&mut self) {
        if !std::mem::take(&mut self.open) {
            return;
        }
        self.done.push(Minute {
            index: self.minute + 1,
            ticks: self.ticks,
            misses: self.misses,
            round_trip: deltaloop_timing::percentiles(&self.round_trip),
            span_s: (self.last_k - self.minute * self.ticks_per_minute) as f64 * self.ts_s,
        });
        self.ticks = 0;
        self.misses = 0;
        self.round_trip.reset();
    }
}

/// Resident memory of the three processes now, MiB (None: not found or not readable).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Rss {
    pub supervisor: Option<f64>,
    pub plant: Option<f64>,
    pub controller: Option<f64>,
    /// A child's value is its peak, read when it exited (it exited before it was sampled).
    pub children_peak: bool,
}

impl Rss {
    /// Each process's newest reading: `now`'s, else the one kept.
    fn update(&mut self, now: Rss) {
        self.supervisor = now.supervisor.or(self.supervisor);
        self.plant = now.plant.or(self.plant);
        self.controller = now.controller.or(self.controller);
    }

    /// Children never sampled get their peak from when they exited (a run shorter than the
    /// sampling period: regression, a short soak's minute printed RSS "?").
    fn fill_from_peak(&mut self, peak: &PeakRss) {
        let before = (self.plant, self.controller);
        self.plant = self.plant.or(peak.plant);
        self.controller = self.controller.or(peak.controller);
        self.children_peak |= before != (self.plant, self.controller);
    }

    /// How long until the next sample, `running` into the soak: short until both children have
    /// been read (they start after the soak does, and a lockstep run may last well under a
    /// second), then 2 s; 2 s too after the first 10 s (children that cannot be read, e.g. in
    /// another PID namespace, do not make it scan `/proc` 50 times a second for hours).
    fn next_sample_in(&self, running: Duration) -> Duration {
        if (self.plant.is_some() && self.controller.is_some()) || running > Duration::from_secs(10)
        {
            Duration::from_secs(2)
        } else {
            Duration::from_millis(20)
        }
    }
}

/// VmRSS of a process, MiB.
fn vm_rss_mib(pid: &str) -> Option<f64> {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
    let kib: f64 = status
        .lines()
        .find_map(|l| l.strip_prefix("VmRSS:"))?
        .trim()
        .trim_end_matches("kB")
        .trim()
        .parse()
        .ok()?;
    Some(kib / 1024.0)
}

/// The supervisor's (this process) and its children's resident memory: a child whose arguments
/// carry `--law` is the controller, the other the plant.
pub fn rss_now() -> Rss {
    let me = std::process::id().to_string();
    let mut rss = Rss {
        supervisor: vm_rss_mib("self"),
        ..Rss::default()
    };
    let Ok(dir) = std::fs::read_dir("/proc") else {
        return rss;
    };
    for e in dir.flatten() {
        let pid = e.file_name().to_string_lossy().into_owned();
        if !pid.bytes().all(|b| b.is_ascii_digit()) {
            continue;
        }
        // /proc/<pid>/stat: "pid (comm) state ppid …"; comm may hold spaces and parentheses.
        let Ok(stat) = std::fs::read_to_string(e.path().join("stat")) else {
            continue;
        };
        let ppid = stat
            .rsplit_once(')')
            .and_then(|(_, rest)| rest.split_whitespace().nth(1));
        if ppid != Some(me.as_str()) {
            continue;
        }
        let cmd = std::fs::read(e.path().join("cmdline")).unwrap_or_default();
        let is_controller = cmd.split(|&b| b == 0).any(|a| a == b"--law");
        let slot = if is_controller {
            &mut rss.controller
        } else {
            &mut rss.plant
        };
        *slot = vm_rss_mib(&pid);
    }
    rss
}

/// `m:ss` or `h:mm:ss`.
pub fn clock(s: f64) -> String {
    let s = s.max(0.0).round() as u64;
    if s >= 3600 {
        format!("{}:{:02}:{:02}", s / 3600, s / 60 % 60, s % 60)
    } else {
        format!("{}:{:02}", s / 60, s % 60)
    }
}

/// The summary line of one minute.
pub fn minute_line(m: &Minute, rss: &Rss) -> String {
    let mib = |v: Option<f64>| v.map_or("n/a (not readable)".into(), |v| format!("{v:.1}"));
    let from = (m.index - 1) as f64 * 60.0;
    let rt = &m.round_trip;
    format!(
        "minute {} ({}–{}{}): {} ticks, {} misses, round trip p50 {:.1} µs p99.9 {:.1} µs max {:.1} µs; RSS MiB supervisor {} plant {} controller {}",
        m.index,
        clock(from),
        clock(from + m.span_s),
        if m.span_s < 59.5 { ", partial" } else { "" },
        m.ticks,
        m.misses,
        rt.p50_us,
        rt.p999_us,
        rt.max_us,
        mib(rss.supervisor),
        mib(rss.plant),
        mib(rss.controller)
    ) + if rss.children_peak {
        " (plant and controller: their peak, read when they exited)"
    } else {
        ""
    }
}

/// How the soak ended, for its last progress line.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct End {
    /// The run's status (`ok` when it completed): the first law that did not end `ok`, or what
    /// the run's error stands for ([`run::error_status`]).
    pub status: RunStatus,
    /// The tick its status names (a divergence's tick), if any.
    pub tick: Option<u64>,
    /// The last run's peak memory (from `wait4`), for children never sampled.
    pub peak: Option<PeakRss>,
}

impl End {
    /// From what the run returned.
    fn of(result: &Result<run::RunOutput>) -> Self {
        match result {
            Ok(o) => {
                let first = o.metrics.iter().find(|m| m.status != RunStatus::Ok);
                Self {
                    status: first.map_or(RunStatus::Ok, |m| m.status),
                    tick: first.and_then(|m| m.status_tick),
                    peak: o.peak_rss.clone(),
                }
            }
            Err(e) => Self {
                status: run::error_status(e),
                tick: None,
                peak: None,
            },
        }
    }
}

/// The soak's last progress line (regression: a soak whose robot diverged ended with a line that
/// looked like a normal end).
pub fn end_line(end: &End, elapsed_s: f64, progress: &str) -> String {
    let how = match (end.status, end.tick) {
        (RunStatus::Ok, _) => "ended".to_string(),
        (RunStatus::Diverged, Some(k)) => format!("diverged at tick {k},"),
        (RunStatus::Diverged, None) => "diverged,".to_string(),
        (RunStatus::Interrupted, _) => "interrupted,".to_string(),
        (RunStatus::Error, _) => "stopped by an error (below),".to_string(),
        (status, _) => format!("ended with status {status} (below),"),
    };
    format!("soak: {how} after {}: {progress}", clock(elapsed_s))
}

/// What `deltaloop soak` was asked for.
pub struct Request<'a> {
    pub config: &'a Path,
    pub duration: Duration,
    pub mode: LoopMode,
    pub overrides: &'a Overrides,
    pub out: Option<PathBuf>,
    pub force: bool,
    pub command: &'a str,
    /// Draw a progress bar (stderr is a terminal); else a plain progress line every 10 s.
    pub tty: bool,
    /// Also write the law's `<law>.mcap` while it records.
    pub mcap: bool,
}

/// Runs the soak: the run's table and folder on stdout at the end, like `deltaloop run`.
pub fn soak(r: Request<'_>) -> Result<()> {
    if !r.mode.is_process() {
        bail!(
            "--mode {}: a soak runs the loop's processes (realtime or lockstep)",
            r.mode.name()
        );
    }
    let mut cfg = run::load_config(r.config, r.overrides)?;
    if cfg.controller.laws.len() != 1 {
        let names: Vec<String> = cfg.controller.laws.iter().map(|l| l.to_string()).collect();
        bail!(
            "a soak runs one law; {} lists {} ({}): choose one with --law",
            r.config.display(),
            names.len(),
            names.join(", ")
        );
    }
    let motion = cfg.motion_duration_s();
    let want = r.duration.as_secs_f64();
    if want < motion {
        bail!(
            "--duration {}: the scenario's motion alone lasts {motion} s; ask for at least that",
            humantime::format_duration(r.duration)
        );
    }
    cfg.scenario.hold_s = want - motion;
    cfg.validate()?;
    let ts = cfg.loop_.ts_s;
    let total = cfg.ticks(motion) + 1;
    let out = r
        .out
        .unwrap_or_else(|| deltaloop_report::default_run_dir(&format!("soak-{}", cfg.name)));

    let shown = humantime::format_duration(r.duration).to_string();
    let asked = format!("--duration {shown}");
    let ask = DiskAsk {
        asked: &asked,
        shorter: "--duration",
    };
    refuse_if_too_big(total, &cfg.record, &out, &ask)?;
    let acc = Arc::new(Mutex::new(MinuteAcc::new(ts)));
    let mut on_tick = {
        let acc = acc.clone();
        move |seen: &Seen| {
            if let Ok(mut a) = acc.lock() {
                a.push(seen);
            }
        }
    };
    eprintln!(
        "soak: {shown} of {} in {} mode ({} ticks; the motion, then a hold of {:.1} s); run folder {}",
        cfg.name,
        r.mode.name(),
        total,
        cfg.scenario.hold_s,
        out.display()
    );
    let done = Arc::new(std::sync::atomic::AtomicBool::new(false));
    let end = Arc::new(Mutex::new(End::default()));
    let reporter = {
        let (acc, done, end, tty) = (acc.clone(), done.clone(), end.clone(), r.tty);
        std::thread::spawn(move || report(&acc, &done, &end, total, ts, tty))
    };
    let tap = super::ros2::live_tap(&cfg, r.overrides.ros2)?;
    let result = run::run(run::RunRequest {
        tap,
        out: Some(out),
        force: r.force,
        reads: run::config_reads(r.config, r.overrides),
        on_tick: Some(&mut on_tick),
        mcap: r.mcap,
        ..run::RunRequest::new(cfg, r.mode, r.command)
    });
    if let Ok(mut a) = acc.lock() {
        a.close();
    }
    if let Ok(mut e) = end.lock() {
        *e = End::of(&result);
    }
    done.store(true, std::sync::atomic::Ordering::Release);
    let _ = reporter.join();
    result?.print();
    Ok(())
}

/// The reporter thread: the progress line, and each finished minute's summary on stdout (with
/// the RSS read when the minute is printed).
fn report(
    acc: &Mutex<MinuteAcc>,
    done: &std::sync::atomic::AtomicBool,
    end: &Mutex<End>,
    total: u64,
    ts: f64,
    tty: bool,
) {
    use std::io::Write;
    let bar = if tty {
        let pb = indicatif::ProgressBar::new(total);
        pb.set_style(
            indicatif::ProgressStyle::with_template(
                "{elapsed_precise} [{bar:30}] {pos}/{len} ticks  {msg}",
            )
            .expect("a valid template")
            .progress_chars("=> "),
        );
        pb
    } else {
        indicatif::ProgressBar::hidden()
    };
    let started = Instant::now();
    let mut last_plain = Instant::now();
    // Sampled every few seconds, each process's newest reading kept: the last minute is printed
    // after the children have exited.
    let mut rss = Rss::default();
    let mut last_rss: Option<Instant> = None;
    loop {
        let finished = done.load(std::sync::atomic::Ordering::Acquire);
        let end = if finished {
            end.lock().map(|e| e.clone()).unwrap_or_default()
        } else {
            End::default()
        };
        if let Some(p) = &end.peak {
            rss.fill_from_peak(p);
        }
        let (minutes, ticks, misses) = match acc.lock() {
            Ok(mut a) => (std::mem::take(&mut a.done), a.total_ticks, a.total_misses),
            Err(_) => return,
        };
        let progress = format!(
            "{ticks} ticks ({} of loop time), {misses} misses",
            clock(ticks as f64 * ts)
        );
        bar.set_position(ticks);
        bar.set_message(format!("{misses} misses"));
        if !finished
            && last_rss.is_none_or(|t| t.elapsed() >= rss.next_sample_in(started.elapsed()))
        {
            last_rss = Some(Instant::now());
            rss.update(rss_now());
        }
        if !minutes.is_empty() {
            for m in &minutes {
                let line = minute_line(m, &rss);
                bar.suspend(|| {
                    let _ = writeln!(std::io::stdout(), "{line}");
                });
            }
        }
        if !tty && last_plain.elapsed() >= Duration::from_secs(10) {
            last_plain = Instant::now();
            let _ = writeln!(
                std::io::stderr(),
                "soak: {} elapsed, {progress}",
                clock(started.elapsed().as_secs_f64())
            );
        }
        if finished {
            bar.finish_and_clear();
            let _ = writeln!(
                std::io::stderr(),
                "{}",
                end_line(&end, started.elapsed().as_secs_f64(), &progress)
            );
            return;
        }
        std::thread::sleep(
            rss.next_sample_in(started.elapsed())
                .min(Duration::from_millis(250)),
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use deltaloop_transport::wire::TelemetryMsg;

    fn seen(k: u64, rt_ns: u64, flags: u32) -> Seen {
        Seen {
            k,
            tel: Some(TelemetryMsg {
                tick: k,
                flags,
                t_state_pub_ns: 1_000,
                t_torque_rx_ns: if flags & wire::TEL_MISSED != 0 {
                    0
                } else {
                    1_000 + rt_ns
                },
                ..TelemetryMsg::default()
            }),
            ..Seen::default()
        }
    }

    #[test]
    fn durations_parse_like_humantime_and_are_bounded() {
        assert_eq!(parse_duration("90s"), Ok(Duration::from_secs(90)));
        assert_eq!(parse_duration("10m"), Ok(Duration::from_secs(600)));
        assert_eq!(parse_duration("2h"), Ok(Duration::from_secs(7200)));
        assert_eq!(parse_duration("1h 30m"), Ok(Duration::from_secs(5400)));
        let e = parse_duration("2 fortnights").unwrap_err();
        assert!(
            e.contains("`2 fortnights` is not a duration") && e.contains("2h"),
            "{e}"
        );
        assert!(parse_duration("25h").unwrap_err().contains("1s ..= 24h"));
        assert!(parse_duration("500ms").is_err());
    }

    /// Ticks fall into minutes by their loop time; each minute has its own percentiles and misses;
    /// the safe stop and ticks without telemetry are not counted; the last minute is partial.
    #[test]
    fn minutes_split_by_loop_time_with_their_own_percentiles() {
        // Ts = 1 s: 60 ticks a minute.
        let mut a = MinuteAcc::new(1.0);
        for k in 0..=150 {
            let rt = if k <= 60 { 10_000 } else { 20_000 };
            let flags = if k == 70 || k == 71 {
                wire::TEL_MISSED
            } else {
                0
            };
            a.push(&seen(k, rt, flags));
        }
        a.push(&Seen {
            k: 151,
            ..Seen::default()
        });
        a.push(&seen(152, 1, wire::TEL_SAFE_STOP));
        a.close();
        let m = &a.done;
        assert_eq!(m.len(), 3);
        assert_eq!(
            (m[0].index, m[0].ticks, m[0].misses, m[0].span_s),
            (1, 61, 0, 60.0)
        );
        assert_eq!((m[1].index, m[1].ticks, m[1].misses), (2, 60, 2));
        assert_eq!((m[2].index, m[2].ticks, m[2].span_s), (3, 30, 30.0));
        assert!((m[0].round_trip.max_us - 10.0).abs() < 0.02);
        assert!((m[1].round_trip.p50_us - 20.0).abs() < 0.03);
        assert_eq!(m[1].round_trip.count, 58);
        assert_eq!((a.total_ticks, a.total_misses), (151, 2));
        let line = minute_line(&m[2], &Rss::default());
        assert!(
            line.starts_with("minute 3 (2:00–2:30, partial): 30 ticks, 0 misses"),
            "{line}"
        );
    }

    /// Regression: a 30 min soak (ticks 0 ..= 6 000 000) printed a 31st "minute" holding only
    /// its last tick.
    #[test]
    fn regression_a_run_of_whole_minutes_ends_with_a_whole_minute_not_a_lone_tick() {
        let mut a = MinuteAcc::new(1.0);
        for k in 0..=120 {
            a.push(&seen(k, 10_000, 0));
        }
        a.close();
        let m = &a.done;
        assert_eq!(m.len(), 2, "{m:?}");
        assert_eq!((m[1].index, m[1].ticks, m[1].span_s), (2, 60, 60.0));
        assert!(!minute_line(&m[1], &Rss::default()).contains("partial"));
    }

    #[test]
    fn a_soak_that_would_fill_the_disk_is_refused_up_front() {
        let ticks = 288_000_000; // 24 h at 3.3 kHz
        let all = RecordSection::default();
        let ask = |asked| DiskAsk {
            asked,
            shorter: "--duration",
        };
        let (day, hour) = (ask("--duration 1day"), ask("--duration 1h"));
        let e = check_disk(ticks, &all, 59_000_000_000, Path::new("runs/x"), &day).unwrap_err();
        assert!(
            e.starts_with("--duration 1day writes about 216.0 GB (288000000 ticks of ≈ 750 B in trace.csv and timing.csv)"),
            "{e}"
        );
        assert!(e.contains("runs/x has 59.0 GB free"), "{e}");
        assert!(check_disk(12_000_000, &all, 59_000_000_000, Path::new("."), &hour).is_ok());
        // Without the trace the day takes 31.7 GB and fits; with no per-tick file nothing grows.
        let timing_only = RecordSection {
            trace: false,
            timing_csv: true,
            explain: false,
        };
        assert!(check_disk(ticks, &timing_only, 59_000_000_000, Path::new("."), &day).is_ok());
        let e = check_disk(ticks, &timing_only, 30_000_000_000, Path::new("."), &day).unwrap_err();
        assert!(e.contains("≈ 110 B in timing.csv)"), "{e}");
        let none = RecordSection {
            trace: false,
            timing_csv: false,
            explain: false,
        };
        assert!(check_disk(u64::MAX, &none, 0, Path::new("."), &day).is_ok());
        // `--explain` keeps the kernel's record of the law on disk until it ends.
        let explained = RecordSection {
            explain: true,
            ..none
        };
        let e = check_disk(ticks, &explained, 59_000_000_000, Path::new("."), &day).unwrap_err();
        assert!(
            e.contains("≈ 1100 B in the kernel's record of --explain"),
            "{e}"
        );
        assert!(
            check_disk(
                12_000_000,
                &explained,
                59_000_000_000,
                Path::new("."),
                &hour
            )
            .is_ok()
        );
        assert!(free_bytes(Path::new("no/such/dir/below/cwd")).is_some_and(|b| b > 0));
    }

    /// Regression: a soak shorter than the sampling period printed RSS "?" for both children.
    #[test]
    fn regression_children_never_sampled_get_their_peak_and_say_so() {
        let mut rss = Rss {
            supervisor: Some(12.0),
            ..Rss::default()
        };
        assert_eq!(
            rss.next_sample_in(Duration::ZERO),
            Duration::from_millis(20)
        );
        assert_eq!(
            rss.next_sample_in(Duration::from_secs(11)),
            Duration::from_secs(2)
        );
        rss.fill_from_peak(&PeakRss {
            supervisor: 13.0,
            plant: Some(5.5),
            controller: Some(4.25),
        });
        let m = Minute {
            index: 1,
            ticks: 10,
            misses: 0,
            round_trip: deltaloop_timing::percentiles(&deltaloop_timing::latency_histogram()),
            span_s: 3.0,
        };
        let line = minute_line(&m, &rss);
        assert!(
            line.ends_with("RSS MiB supervisor 12.0 plant 5.5 controller 4.2 (plant and controller: their peak, read when they exited)"),
            "{line}"
        );
        assert!(!line.contains('?'), "{line}");
        // Sampled children keep their own reading, and the note is not added.
        let mut sampled = Rss {
            supervisor: Some(12.0),
            plant: Some(6.0),
            controller: Some(4.0),
            children_peak: false,
        };
        assert_eq!(
            sampled.next_sample_in(Duration::ZERO),
            Duration::from_secs(2)
        );
        sampled.fill_from_peak(&PeakRss::default());
        assert!(!sampled.children_peak && sampled.plant == Some(6.0));
        // A value that could not be read says so rather than "?".
        assert!(minute_line(&m, &Rss::default()).contains("plant n/a (not readable)"));
    }

    /// Regression: the last progress line of a soak that diverged looked like a normal end.
    #[test]
    fn regression_the_last_progress_line_says_diverged() {
        let end = End {
            status: RunStatus::Diverged,
            tick: Some(4711),
            peak: None,
        };
        assert_eq!(
            end_line(&end, 65.0, "4712 ticks (0:01 of loop time), 0 misses"),
            "soak: diverged at tick 4711, after 1:05: 4712 ticks (0:01 of loop time), 0 misses"
        );
        assert!(end_line(&End::default(), 65.0, "x").starts_with("soak: ended after 1:05"));
    }

    #[test]
    fn rss_of_this_process_is_read() {
        let r = rss_now();
        assert!(r.supervisor.is_some_and(|m| m > 0.5), "{r:?}");
    }
}
