//! Files the bridge reads and writes where another user may have planted a link: opened without
//! following one, created only new and private.

use std::io::{Read, Write};
use std::os::unix::fs::OpenOptionsExt;
use std::path::Path;

/// The largest file read here (a key file, a config), bytes.
const MAX_READ: u64 = 1 << 20;

/// Reads a regular file without following a link at `path` (nor blocking on a FIFO), at most
/// 1 MiB.
pub fn read_no_follow(path: &Path) -> std::io::Result<Vec<u8>> {
    let f = std::fs::OpenOptions::new()
        .read(true)
        .custom_flags(libc::O_NOFOLLOW | libc::O_NONBLOCK)
        .open(path)?;
    if !f.metadata()?.is_file() {
        return Err(std::io::Error::other("not a regular file"));
    }
    let mut out = Vec::new();
    f.take(MAX_READ).read_to_end(&mut out)?;
    Ok(out)
}

/// Creates `path` new (never an existing file, and never through a link), mode 600, holding
/// `bytes`.
pub fn create_private(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    let mut f = std::fs::OpenOptions::new()
        .write(true)
        .create_new(true)
        .mode(0o600)
        .custom_flags(libc::O_NOFOLLOW)
        .open(path)?;
    f.write_all(bytes)?;
    f.sync_all()
}
