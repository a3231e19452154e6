//! The far side of one run over this host's loopback, for a sweep's `link_delay_us` axis: the
//! controller runs behind `deltaloop-bridge far` (what `deltaloop join … --role controller`
//! runs) with an iceoryx2 root of its own (`DELTALOOP_IOX2_ROOT`), so the link is the only path
//! between the plant's side and the controller's even on one machine, and the near bridge takes
//! the controller's place as with `deltaloop run --controller-remote 127.0.0.1:PORT`. A free port
//! per run. Dropping a [`LoopbackFar`] stops the far bridge if it still runs (SIGTERM, then
//! SIGKILL) and removes its root: its files and its shared memory, on success, on an error and
//! after Ctrl-C alike.

use crate::procs::exe_dir;
use crate::run::Interrupted;
use crate::signals;
use anyhow::{Context, Result, bail};
use std::net::{Ipv4Addr, SocketAddr, TcpListener, UdpSocket};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Stdio};
use std::sync::atomic::{AtomicU32, Ordering};
use std::time::{Duration, Instant};

/// A child that is stopped (SIGTERM, then SIGKILL) and reaped if dropped still running.
pub struct Kid(Child, &'static str);

impl Kid {
    /// Starts `c` with its stdout and stderr in `log`.
    pub fn spawn(mut c: Command, what: &'static str, log: &Path) -> Result<Self> {
        let f = std::fs::File::create(log)
            .with_context(|| format!("cannot create {}", log.display()))?;
        c.stdout(f.try_clone()?).stderr(f).stdin(Stdio::null());
        Ok(Kid(
            c.spawn().with_context(|| format!("cannot start {what}"))?,
            what,
        ))
    }

    pub fn signal(&self, sig: i32) {
        // SAFETY: our own child, not yet reaped (it is reaped only through self.0).
        unsafe { libc::kill(self.0.id() as i32, sig) };
    }

    /// Waits up to `limit`; an error on Ctrl-C / SIGTERM (the child stopped first) or timeout.
    pub fn wait(&mut self, limit: Duration, out: &Path) -> Result<ExitStatus> {
        let t0 = Instant::now();
        loop {
            if let Some(s) = self.0.try_wait()? {
                return Ok(s);
            }
            if signals::interrupted() {
                self.signal(libc::SIGINT);
                return Err(Interrupted(out.to_path_buf()).into());
            }
            if t0.elapsed() > limit {
                bail!("{} did not end within {} s", self.1, limit.as_secs());
            }
            std::thread::sleep(Duration::from_millis(20));
        }
    }
}

impl Drop for Kid {
    fn drop(&mut self) {
        if matches!(self.0.try_wait(), Ok(None)) {
            self.signal(libc::SIGTERM);
            let t0 = Instant::now();
            while matches!(self.0.try_wait(), Ok(None)) && t0.elapsed() < Duration::from_secs(3) {
                std::thread::sleep(Duration::from_millis(20));
            }
            let _ = self.0.kill();
            let _ = self.0.wait();
        }
    }
}

/// Removes what an iceoryx2 root (`DELTALOOP_IOX2_ROOT=root`) holds on this machine: the shared
/// memory under its prefix (docs/protocol.md §14) and, with `dir`, the folder itself.
pub fn remove_root(root: &Path, dir: bool) {
    if let Some((_, prefix)) = root.to_str().and_then(deltaloop_transport::ipc::root_of)
        && let Ok(rd) = std::fs::read_dir("/dev/shm")
    {
        for e in rd.flatten() {
            if e.file_name().to_string_lossy().starts_with(&prefix) {
                let _ = std::fs::remove_file(e.path());
            }
        }
    }
    if dir {
        let _ = std::fs::remove_dir_all(root);
    }
}

/// A port of 127.0.0.1 free for both TCP and UDP right now (the near bridge binds both).
fn free_port() -> Result<u16> {
    let any = SocketAddr::from((Ipv4Addr::LOCALHOST, 0));
    for _ in 0..20 {
        let tcp = TcpListener::bind(any).context("cannot bind a TCP port on 127.0.0.1")?;
        let port = tcp.local_addr()?.port();
        if UdpSocket::bind((Ipv4Addr::LOCALHOST, port)).is_ok() {
            return Ok(port);
        }
    }
    bail!("no port of 127.0.0.1 is free for both TCP and UDP (20 tries)")
}

/// The far bridge of one run over loopback, with its own iceoryx2 root.
pub struct LoopbackFar {
    kid: Option<Kid>,
    root: PathBuf,
    /// `127.0.0.1:PORT`: what the near bridge listens on (`--controller-remote`).
    pub endpoint: String,
}

impl LoopbackFar {
    /// Starts `deltaloop-bridge far --role controller --runs 1` towards a free port of
    /// 127.0.0.1, its stderr in `log`; it keeps trying to connect until the near bridge listens
    /// (at most 30 s).
    pub fn start(log: &Path) -> Result<Self> {
        static N: AtomicU32 = AtomicU32::new(0);
        let root = std::env::temp_dir().join(format!(
            "deltaloop-link-{}-{}",
            std::process::id(),
            N.fetch_add(1, Ordering::Relaxed)
        ));
        std::fs::create_dir_all(&root)
            .with_context(|| format!("cannot make the far side's root {}", root.display()))?;
        let mut far = LoopbackFar {
            kid: None,
            root,
            endpoint: format!("127.0.0.1:{}", free_port()?),
        };
        let bridge = exe_dir()?.join("deltaloop-bridge");
        let mut c = Command::new(&bridge);
        // The sweep's own one-time key, which its near bridges get too.
        crate::link_key::one_time_link_key()?;
        crate::link_key::hand_key(&mut c, &bridge, Some("far"));
        c.args(["far", "--role", "controller", "--runs=1", "--wait-s=30"])
            .arg(format!("--connect={}", far.endpoint))
            .env(deltaloop_transport::ipc::ROOT_ENV, &far.root);
        // Its own process group: the terminal's Ctrl-C reaches the supervisor, which stops the
        // run in order (STOP crosses the link); a supervisor killed outright takes it along.
        std::os::unix::process::CommandExt::process_group(&mut c, 0);
        deltaloop_transport::rt::die_with_parent(&mut c);
        far.kid = Some(Kid::spawn(c, "deltaloop-bridge far", log).with_context(|| {
            format!(
                "{} (build it: `cargo build --release` puts it next to deltaloop)",
                bridge.display()
            )
        })?);
        Ok(far)
    }

    /// After the run: the far bridge's exit status, waiting up to `limit` for it (it reports
    /// its controller's end first); None if it had to be stopped.
    pub fn finish(mut self, limit: Duration) -> Option<ExitStatus> {
        let kid = self.kid.as_mut()?;
        let t0 = Instant::now();
        loop {
            match kid.0.try_wait() {
                Ok(Some(s)) => return Some(s),
                Ok(None) if t0.elapsed() < limit => std::thread::sleep(Duration::from_millis(10)),
                _ => return None,
            }
        }
    }
}

impl Drop for LoopbackFar {
    fn drop(&mut self) {
        // The bridge first (it may still hold its shared memory), then its root.
        drop(self.kid.take());
        remove_root(&self.root, true);
    }
}
