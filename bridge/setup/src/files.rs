//! Files a bridge or the supervisor reads and writes where another user may have planted a link: opened without
//! following one, created only new and private.

use std::io::{Read, Write};
use std::os::unix::fs::OpenOptionsExt;
use std::path::Path;

/// The largest file read here (a key file, a config), bytes.
const MAX_READ: u64 = 1 << 20;

/// Reads a regular file without following a link at `path` (nor blocking on a FIFO); a file
/// larger than 1 MiB is refused, never cut.
pub fn read_no_follow(path: &Path) -> std::io::Result<Vec<u8>> {
    let f = std::fs::OpenOptions::new()
        .read(true)
        .custom_flags(libc::O_NOFOLLOW | libc::O_NONBLOCK)
        .open(path)?;
    if !f.metadata()?.is_file() {
        return Err(std::io::Error::other("not a regular file"));
    }
    let mut out = Vec::new();
    // One byte more than allowed: a file that fills it is too large (also one that grew since).
    f.take(MAX_READ + 1).read_to_end(&mut out)?;
    if out.len() as u64 > MAX_READ {
        return Err(std::io::Error::other(format!(
            "larger than {} bytes (allowed at most {MAX_READ})",
            MAX_READ
        )));
    }
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

#[cfg(test)]
mod tests {
    use super::*;

    /// Regression: a file over 1 MiB was read cut at 1 MiB, silently (a key file or config of
    /// that size is no honest one): it is refused, saying its limit.
    #[test]
    fn regression_a_file_over_the_limit_is_refused_not_cut() {
        let dir = tempfile::tempdir().unwrap();
        let (fits, over) = (dir.path().join("fits"), dir.path().join("over"));
        std::fs::write(&fits, vec![b'a'; MAX_READ as usize]).unwrap();
        std::fs::write(&over, vec![b'a'; MAX_READ as usize + 1]).unwrap();
        assert_eq!(read_no_follow(&fits).unwrap().len(), MAX_READ as usize);
        let e = read_no_follow(&over).unwrap_err().to_string();
        assert!(e.contains("allowed at most 1048576"), "{e}");
    }
}
