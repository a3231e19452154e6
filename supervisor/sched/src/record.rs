//! Recording the kernel's scheduling events on the loop's CPUs: a tracefs instance of its own
//! (so a system-wide tracer is left alone), its per-CPU ring buffers limited to those CPUs by
//! `tracing_cpumask`, stamped with CLOCK_MONOTONIC (`trace_clock = mono`, the clock of the loop's
//! own stamps), drained by a SCHED_OTHER thread of the supervisor (off the loop's CPUs) into a
//! file, with the CPUs' steal clock sampled between reads.

use crate::event::EVENTS;
use std::fs::{File, OpenOptions};
use std::io::{ErrorKind, Read, Write};
use std::os::unix::fs::OpenOptionsExt;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::thread::JoinHandle;
use std::time::Duration;

/// Where tracefs is mounted (the first that exists).
const TRACEFS: [&str; 2] = ["/sys/kernel/tracing", "/sys/kernel/debug/tracing"];

/// Each CPU's ring buffer, KiB: at 3.3 kHz a loop CPU logs ≈ 30 k events a second (≈ 2 MB/s of
/// ring), drained every 2 ms.
const BUFFER_KB: u32 = 4096;

/// How often the reader drains the buffers and samples steal.
const EVERY: Duration = Duration::from_millis(2);

/// Instances are named after the supervisor's pid: one left by a killed supervisor is removed by
/// the next recorder.
const PREFIX: &str = "deltaloop-";

/// The kernel's record of a run, being made.
pub struct Recorder {
    instance: PathBuf,
    stop: Arc<AtomicBool>,
    reader: Option<JoinHandle<std::io::Result<Counts>>>,
}

/// What a recording holds.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Counts {
    /// Lines of events read.
    pub lines: u64,
    /// Bytes read from the ring buffers.
    pub bytes: u64,
    /// Seconds the recording ran.
    pub seconds: f64,
}

impl Counts {
    /// Events a second (lines of the record over its duration).
    pub fn per_second(&self) -> f64 {
        if self.seconds > 0.0 {
            self.lines as f64 / self.seconds
        } else {
            0.0
        }
    }
}

impl Recorder {
    /// Starts recording the events of CPUs `cpus` into the file `to`. Err(why, one line) when
    /// this host cannot: no tracefs, no rights (root is needed), or events it lacks.
    pub fn start(cpus: &[usize], to: &Path) -> Result<Self, String> {
        let root = TRACEFS
            .iter()
            .map(Path::new)
            .find(|p| p.join("instances").is_dir())
            .ok_or_else(|| {
                format!(
                    "no tracefs at {} (mount -t tracefs nodev /sys/kernel/tracing)",
                    TRACEFS[0]
                )
            })?;
        remove_stale(root);
        let instance = root
            .join("instances")
            .join(format!("{PREFIX}{}", std::process::id()));
        if instance.exists() {
            let _ = std::fs::remove_dir(&instance);
        }
        std::fs::create_dir(&instance).map_err(|e| {
            let hint = if e.kind() == ErrorKind::PermissionDenied {
                " (root is needed)"
            } else {
                ""
            };
            format!("cannot create {}: {e}{hint}", instance.display())
        })?;
        let mut r = Self {
            instance,
            stop: Arc::new(AtomicBool::new(false)),
            reader: None,
        };
        r.configure(cpus)?;
        let pipe = OpenOptions::new()
            .read(true)
            .custom_flags(libc::O_NONBLOCK)
            .open(r.instance.join("trace_pipe"))
            .map_err(|e| format!("cannot read {}: {e}", r.instance.display()))?;
        let out = File::create(to).map_err(|e| format!("cannot write {}: {e}", to.display()))?;
        r.set("tracing_on", "1")?;
        let (stop, cpus) = (r.stop.clone(), cpus.to_vec());
        r.reader = Some(
            std::thread::Builder::new()
                .name("sched-record".into())
                .spawn(move || {
                    keep_off(&cpus);
                    drain(pipe, out, &cpus, &stop)
                })
                .map_err(|e| format!("cannot start the reader thread: {e}"))?,
        );
        Ok(r)
    }

    fn configure(&self, cpus: &[usize]) -> Result<(), String> {
        let mask = cpus.iter().fold(0u128, |m, &c| m | (1u128 << c.min(127)));
        self.set("tracing_on", "0")?;
        self.set("trace_clock", "mono")?;
        self.set("buffer_size_kb", &BUFFER_KB.to_string())?;
        self.set("tracing_cpumask", &format!("{mask:x}"))?;
        for e in EVENTS {
            self.set(&format!("events/{e}/enable"), "1")?;
        }
        Ok(())
    }

    fn set(&self, file: &str, value: &str) -> Result<(), String> {
        std::fs::write(self.instance.join(file), value).map_err(|e| {
            format!(
                "cannot set {} to {value}: {e}",
                self.instance.join(file).display()
            )
        })
    }

    /// Stops recording, drains what is left and removes the instance.
    pub fn stop(mut self) -> Result<Counts, String> {
        let _ = self.set("tracing_on", "0");
        self.stop.store(true, Ordering::Release);
        let counts = match self.reader.take().map(JoinHandle::join) {
            Some(Ok(Ok(c))) => Ok(c),
            Some(Ok(Err(e))) => Err(format!("the kernel's record could not be written: {e}")),
            _ => Err("the kernel's record reader failed".into()),
        };
        let _ = std::fs::remove_dir(&self.instance);
        counts
    }
}

impl Drop for Recorder {
    fn drop(&mut self) {
        if let Some(r) = self.reader.take() {
            let _ = std::fs::write(self.instance.join("tracing_on"), "0");
            self.stop.store(true, Ordering::Release);
            let _ = r.join();
        }
        let _ = std::fs::remove_dir(&self.instance);
    }
}

/// Moves the calling thread off the loop's CPUs `cpus`, to the others this process may use (if
/// it may use none, it stays: the loop's layout shares the supervisor's CPU with the loop).
fn keep_off(cpus: &[usize]) {
    // SAFETY: cpu_set_t is plain data; zeroed is the empty set.
    let mut set: libc::cpu_set_t = unsafe { std::mem::zeroed() };
    // SAFETY: getting the calling thread's affinity into our set.
    if unsafe { libc::sched_getaffinity(0, std::mem::size_of_val(&set), &mut set) } != 0 {
        return;
    }
    let mut left = 0;
    for c in 0..libc::CPU_SETSIZE as usize {
        // SAFETY: c is below CPU_SETSIZE.
        if unsafe { libc::CPU_ISSET(c, &set) } {
            if cpus.contains(&c) {
                // SAFETY: as above.
                unsafe { libc::CPU_CLR(c, &mut set) };
            } else {
                left += 1;
            }
        }
    }
    if left == 0 {
        // The process may run only on loop CPUs: try every other CPU of the machine.
        // SAFETY: as above.
        set = unsafe { std::mem::zeroed() };
        let n = std::thread::available_parallelism().map_or(0, |n| n.get());
        for c in (0..n.max(1)).filter(|c| !cpus.contains(c)) {
            // SAFETY: as above.
            unsafe { libc::CPU_SET(c, &mut set) };
            left += 1;
        }
    }
    if left > 0 {
        // SAFETY: a valid set for the calling thread; a refusal leaves its affinity as it was.
        unsafe { libc::sched_setaffinity(0, std::mem::size_of_val(&set), &set) };
    }
}

/// Removes instances of supervisors that are gone.
fn remove_stale(root: &Path) {
    let Ok(dir) = std::fs::read_dir(root.join("instances")) else {
        return;
    };
    for e in dir.flatten() {
        let name = e.file_name().to_string_lossy().into_owned();
        let Some(pid) = name
            .strip_prefix(PREFIX)
            .and_then(|p| p.parse::<u32>().ok())
        else {
            continue;
        };
        if !Path::new(&format!("/proc/{pid}")).exists() {
            let _ = std::fs::remove_dir(e.path());
        }
    }
}

/// The reader: every [`EVERY`], what the ring buffers hold, then a steal line per CPU; after
/// `stop`, what is left.
fn drain(mut pipe: File, out: File, cpus: &[usize], stop: &AtomicBool) -> std::io::Result<Counts> {
    let mut out = std::io::BufWriter::with_capacity(1 << 16, out);
    let mut buf = vec![0u8; 1 << 16];
    let mut c = Counts::default();
    let t0 = mono_ns();
    loop {
        let stopping = stop.load(Ordering::Acquire);
        loop {
            match pipe.read(&mut buf) {
                Ok(0) => break,
                Ok(n) => {
                    out.write_all(&buf[..n])?;
                    c.bytes += n as u64;
                    c.lines += buf[..n].iter().filter(|&&b| b == b'\n').count() as u64;
                }
                Err(e) if e.kind() == ErrorKind::WouldBlock => break,
                Err(e) if e.kind() == ErrorKind::Interrupted => {}
                Err(e) => return Err(e),
            }
        }
        let now = mono_ns();
        for (cpu, jiffies) in steal_jiffies()
            .into_iter()
            .filter(|(c, _)| cpus.contains(c))
        {
            writeln!(out, "steal cpu={cpu} jiffies={jiffies} t={now}")?;
        }
        if stopping {
            break;
        }
        std::thread::sleep(EVERY);
    }
    out.flush()?;
    c.seconds = mono_ns().saturating_sub(t0) as f64 / 1e9;
    Ok(c)
}

/// CLOCK_MONOTONIC, ns (the clock of `trace_clock = mono`).
fn mono_ns() -> u64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: a valid out-pointer; CLOCK_MONOTONIC always exists.
    unsafe { libc::clock_gettime(libc::CLOCK_MONOTONIC, &mut ts) };
    ts.tv_sec as u64 * 1_000_000_000 + ts.tv_nsec as u64
}

/// Each CPU's steal clock, (CPU index, jiffies) (/proc/stat's `steal`: time the hypervisor ran
/// something else while this virtual CPU had work); empty where /proc/stat is unavailable.
pub fn steal_jiffies() -> Vec<(usize, u64)> {
    let Ok(text) = std::fs::read_to_string("/proc/stat") else {
        return Vec::new();
    };
    text.lines()
        .filter_map(|l| {
            let mut f = l.split_whitespace();
            let cpu = f.next()?.strip_prefix("cpu")?.parse::<usize>().ok()?;
            // user nice system idle iowait irq softirq steal
            let steal = f.nth(7)?.parse::<u64>().ok()?;
            Some((cpu, steal))
        })
        .collect()
}
