//! What every use of iceoryx2 in this crate shares: the service variant, and the error that
//! says what was being done.

use crate::wire;
use std::fmt::Debug;

/// The iceoryx2 service variant: inter-process, shared memory.
pub type Svc = iceoryx2::service::ipc::Service;

/// A transport error, with what was being set up.
#[derive(Debug, thiserror::Error)]
#[error("iceoryx2: {what}: {detail}")]
pub struct IpcError {
    pub what: String,
    pub detail: String,
}

/// Names what was being done when an iceoryx2 call failed: `port.receive().ipc("receive state")?`.
pub trait IpcContext<T> {
    /// Turns the error into an [`IpcError`] that says `what`.
    fn ipc(self, what: impl Into<String>) -> Result<T, IpcError>;
}

impl<T, E: Debug> IpcContext<T> for Result<T, E> {
    fn ipc(self, what: impl Into<String>) -> Result<T, IpcError> {
        self.map_err(|e| IpcError {
            what: what.into(),
            detail: format!("{e:?}"),
        })
    }
}

/// A process as a message names it: `pid 1234, \`its command line\`` (escaped; the pid alone when
/// its command line cannot be read, 0 when iceoryx2 could not say).
pub fn describe_process(pid: u32) -> String {
    let cmd = std::fs::read(format!("/proc/{pid}/cmdline"))
        .map(|c| {
            let c = String::from_utf8_lossy(&c).replace('\0', " ");
            wire::escape_peer_text(c.trim())
        })
        .unwrap_or_default();
    if cmd.is_empty() {
        format!("pid {pid}")
    } else {
        format!("pid {pid}, `{cmd}`")
    }
}
