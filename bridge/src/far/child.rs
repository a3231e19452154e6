//! The far side's process: its private folder for the run's files and the child it starts.

use super::*;

/// The ports of the role this side serves.
pub(super) enum Either {
    Controller(Ports),
    Plant(PlantSidePorts),
}

/// Removes the run's temporary folder (its config) when the run is over.
pub(super) struct TempDir(pub(super) PathBuf);

/// The prefix of a far bridge's private folder in the temporary directory.
pub(super) const DIR_PREFIX: &str = "deltaloop-join-";

/// A new folder of this process for run `run_id`, mode 700, under a name no one can guess
/// (regression: the name was `deltaloop-join-<pid>-<run id>`, and a link planted there made
/// `join` write the run's config through it). Never an existing path.
pub(super) fn private_dir(run_id: &str) -> Result<PathBuf> {
    use std::os::unix::fs::DirBuilderExt;
    let salt: [u8; 8] = crate::seal::random_bytes().map_err(anyhow::Error::msg)?;
    let salt: String = salt.iter().map(|b| format!("{b:02x}")).collect();
    let dir = std::env::temp_dir().join(format!(
        "{DIR_PREFIX}{}-{run_id}-{salt}",
        std::process::id()
    ));
    std::fs::DirBuilder::new()
        .mode(0o700)
        .create(&dir)
        .with_context(|| format!("cannot create {}", dir.display()))?;
    Ok(dir)
}

/// Removes what far bridges killed outright left behind: their private folders (a process that
/// is gone named in the folder's name) and their dead iceoryx2 nodes' resources (regression: a
/// far bridge killed with -9 left 17 entries, 11 MiB, in /dev/shm and its folder, and no later
/// `join` removed them). Says what it removed.
pub fn remove_leftovers() {
    let mut gone = 0;
    if let Ok(rd) = std::fs::read_dir(std::env::temp_dir()) {
        for e in rd.flatten() {
            let name = e.file_name().to_string_lossy().into_owned();
            let Some(pid) = name
                .strip_prefix(DIR_PREFIX)
                .and_then(|r| r.split('-').next())
                .and_then(|p| p.parse::<i32>().ok())
            else {
                continue;
            };
            // SAFETY: kill with signal 0 only asks whether the process exists.
            let alive = unsafe { libc::kill(pid, 0) } == 0
                || std::io::Error::last_os_error().raw_os_error() == Some(libc::EPERM);
            // SAFETY: geteuid has no preconditions.
            let me = unsafe { libc::geteuid() };
            let mine = e
                .metadata()
                .is_ok_and(|m| std::os::unix::fs::MetadataExt::uid(&m) == me);
            if !alive && mine && std::fs::remove_dir_all(e.path()).is_ok() {
                gone += 1;
            }
        }
    }
    let nodes = ipc::remove_dead_nodes();
    if gone > 0 || !nodes.is_empty() {
        eprintln!(
            "deltaloop-bridge: removed what earlier far bridges killed outright left: {gone} folder(s), the iceoryx2 resources of {} dead node(s)",
            nodes.len()
        );
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

pub(super) fn spawn(
    cmd: &[String],
    run_id: &str,
    mode: LoopMode,
    config: &std::path::Path,
    law: Option<&str>,
    handoff: &deltaloop_transport::handoff::End,
) -> Result<FarChild> {
    let what = if law.is_some() { "controller" } else { "plant" };
    let mut c = Command::new(&cmd[0]);
    c.args(&cmd[1..])
        .args(["--run-id", run_id, "--config"])
        .arg(config)
        .args(["--mode", mode.name()])
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::piped());
    if let Some(law) = law {
        c.args(["--law", law]);
    }
    // The link key is this bridge's, never the process's it starts.
    crate::seal::scrub_secrets(&mut c);
    rt::die_with_parent(&mut c);
    // The process may take the link's socket at START (the direct path).
    deltaloop_transport::handoff::inherit(&mut c, handoff);
    let child = c
        .spawn()
        .with_context(|| format!("cannot start the {what} `{}`", cmd.join(" ")))?;
    if let Some(e) = &child.stderr {
        use std::os::fd::AsRawFd;
        // SAFETY: setting O_NONBLOCK on a pipe descriptor we own.
        unsafe {
            let fl = libc::fcntl(e.as_raw_fd(), libc::F_GETFL);
            libc::fcntl(e.as_raw_fd(), libc::F_SETFL, fl | libc::O_NONBLOCK);
        }
    }
    Ok(FarChild {
        child,
        what,
        stderr_buf: Vec::with_capacity(4096),
        last_line: String::new(),
    })
}

/// The process this side started, its stderr and its end.
pub(super) struct FarChild {
    pub(super) child: Child,
    /// `controller` or `plant`.
    pub(super) what: &'static str,
    pub(super) stderr_buf: Vec<u8>,
    pub(super) last_line: String,
}

impl Drop for FarChild {
    fn drop(&mut self) {
        if self.child.try_wait().ok().flatten().is_none() {
            // SAFETY: signalling our own child, not yet reaped.
            unsafe { libc::kill(self.child.id() as i32, libc::SIGTERM) };
            for _ in 0..200 {
                if self.child.try_wait().ok().flatten().is_some() {
                    return;
                }
                std::thread::sleep(Duration::from_millis(5));
            }
            let _ = self.child.kill();
            let _ = self.child.wait();
        }
    }
}
