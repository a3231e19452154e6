//! Opening the files deltaloop reads (scenario and sweep files, a run's `trace.csv`, a shard's
//! tables): only a regular file, and never more of it than that kind of file can hold. A FIFO
//! would block the reader for ever (SIGINT included: the open itself waits for a writer), and a
//! device such as `/dev/zero` never ends. One implementation for every reader, so no command
//! forgets a case.
//!
//! Errors are the reason alone ("it is a FIFO (named pipe), not a regular file"); the caller
//! names the file.

use rustix::fs::{Mode, OFlags};
use std::fs::File;
use std::io::Read;
use std::path::Path;

/// What kind of file a non-regular file is, for errors ("a FIFO (named pipe)").
pub fn kind_of(t: std::fs::FileType) -> &'static str {
    if t.is_symlink() {
        return "a symbolic link";
    }
    #[cfg(unix)]
    {
        use std::os::unix::fs::FileTypeExt;
        if t.is_fifo() {
            return "a FIFO (named pipe)";
        }
        if t.is_char_device() {
            return "a character device";
        }
        if t.is_block_device() {
            return "a block device";
        }
        if t.is_socket() {
            return "a socket";
        }
    }
    if t.is_dir() {
        "a directory"
    } else {
        "a special file"
    }
}

/// `n` bytes for a message: `1 MiB` when whole MiB, else `1536 KiB` or `100 bytes`.
pub fn show_bytes(n: u64) -> String {
    match n {
        n if n >= 1 << 20 && n % (1 << 20) == 0 => format!("{} MiB", n >> 20),
        n if n >= 1 << 10 && n % (1 << 10) == 0 => format!("{} KiB", n >> 10),
        n => format!("{n} bytes"),
    }
}

/// "it is N bytes, larger than CAP, the limit for WHAT".
fn too_big(size: u64, cap: u64, what: &str) -> String {
    format!(
        "it is {size} bytes, larger than {}, the limit for {what}",
        show_bytes(cap)
    )
}

/// A regular file open for reading that fails a read past its cap (a file that grows while it
/// is read, or was appended to after it was checked).
#[derive(Debug)]
pub struct Capped {
    file: File,

    /// Bytes read so far.
    read: u64,
    cap: u64,
    what: String,
}

impl Read for Capped {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        // One byte past the cap is enough to tell the file is too large.
        let room = self.cap.saturating_add(1).saturating_sub(self.read);
        let want = buf.len().min(usize::try_from(room).unwrap_or(usize::MAX));
        let n = self.file.read(&mut buf[..want])?;
        self.read += n as u64;
        if self.read > self.cap {
            return Err(std::io::Error::other(format!(
                "it grew while read: larger than {}, the limit for {}",
                show_bytes(self.cap),
                self.what
            )));
        }
        Ok(n)
    }
}

/// Opens `path` for reading if it is a regular file, of any size (for a reader that bounds
/// what it reads itself, e.g. a log read from its end). Symbolic links are followed (a link to a
/// scenario is fine); what counts is what was opened: the check is on the open descriptor, so a
/// path swapped after a check cannot slip through. The open is non-blocking (a FIFO cannot hold
/// it), and blocking again once the file is known to be regular.
pub fn open_regular_file(path: &Path) -> Result<File, String> {
    let fd = rustix::fs::open(
        path,
        OFlags::RDONLY | OFlags::NONBLOCK | OFlags::CLOEXEC | OFlags::NOCTTY,
        Mode::empty(),
    )
    .map_err(|e| {
        // A socket cannot be opened at all (ENXIO): say what it is rather than the errno.
        match std::fs::metadata(path) {
            Ok(m) if !m.is_file() => {
                format!("it is {}, not a regular file", kind_of(m.file_type()))
            }
            _ => std::io::Error::from(e).to_string(),
        }
    })?;
    let file = File::from(fd);
    let meta = file.metadata().map_err(|e| e.to_string())?;
    if !meta.is_file() {
        return Err(format!(
            "it is {}, not a regular file",
            kind_of(meta.file_type())
        ));
    }
    let flags = rustix::fs::fcntl_getfl(&file).map_err(|e| std::io::Error::from(e).to_string())?;
    rustix::fs::fcntl_setfl(&file, flags - OFlags::NONBLOCK)
        .map_err(|e| std::io::Error::from(e).to_string())?;
    Ok(file)
}

/// Opens `path` for reading if it is a regular file of at most `cap` bytes (`what` names the
/// kind of file in the error, e.g. "a config file"); see [`open_regular_file`].
pub fn open_regular(path: &Path, cap: u64, what: &str) -> Result<Capped, String> {
    let file = open_regular_file(path)?;
    let len = file.metadata().map_err(|e| e.to_string())?.len();
    if len > cap {
        return Err(too_big(len, cap, what));
    }
    Ok(Capped {
        file,
        read: 0,
        cap,
        what: what.to_string(),
    })
}

/// Reads a whole regular file of at most `cap` bytes (see [`open_regular`]).
pub fn read_regular(path: &Path, cap: u64, what: &str) -> Result<Vec<u8>, String> {
    let mut f = open_regular(path, cap, what)?;
    let mut bytes = Vec::new();
    f.read_to_end(&mut bytes).map_err(|e| e.to_string())?;
    Ok(bytes)
}

/// Reads a whole regular file of at most `cap` bytes as UTF-8 text (see [`open_regular`]).
pub fn read_text(path: &Path, cap: u64, what: &str) -> Result<String, String> {
    String::from_utf8(read_regular(path, cap, what)?).map_err(|e| {
        format!(
            "it is not UTF-8 text (invalid byte at offset {})",
            e.utf8_error().valid_up_to()
        )
    })
}

/// Largest config or sweep file read, bytes (1 MiB). A scenario file is a few hundred bytes.
pub const MAX_FILE_BYTES: u64 = 1 << 20;

/// Reads a config-like text file (a scenario or a sweep file): [`read_text`] with
/// [`MAX_FILE_BYTES`]. The error is the reason alone; the caller names the file.
pub fn read_text_file(path: &Path) -> Result<String, String> {
    read_text(path, MAX_FILE_BYTES, "a config file")
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tmp(tag: &str) -> std::path::PathBuf {
        let d = std::env::temp_dir().join(format!("deltaloop-files-{tag}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).unwrap();
        d
    }

    /// Regression: a FIFO where a file was expected blocked the reader for ever (the open waits
    /// for a writer); now the open returns at once and the FIFO is refused.
    #[test]
    fn regression_fifo_is_refused_without_blocking() {
        let d = tmp("fifo");
        let fifo = d.join("fifo");
        let made = std::process::Command::new("mkfifo")
            .arg(&fifo)
            .status()
            .is_ok_and(|s| s.success());
        assert!(made, "mkfifo");
        let (tx, rx) = std::sync::mpsc::channel();
        let f = fifo.clone();
        std::thread::spawn(move || {
            let _ = tx.send(read_regular(&f, 100, "a test file"));
        });
        let r = rx
            .recv_timeout(std::time::Duration::from_secs(10))
            .expect("open_regular blocked on a FIFO");
        assert_eq!(
            r.unwrap_err(),
            "it is a FIFO (named pipe), not a regular file"
        );
        let _ = std::fs::remove_dir_all(&d);
    }

    /// A link to an endless device is refused (it would grow memory until the OOM killer); so is
    /// a directory; a link to a regular file is read.
    #[test]
    fn devices_and_directories_are_refused_links_to_files_followed() {
        let d = tmp("dev");
        let zero = d.join("zero");
        std::os::unix::fs::symlink("/dev/zero", &zero).unwrap();
        assert_eq!(
            read_regular(&zero, 100, "a test file").unwrap_err(),
            "it is a character device, not a regular file"
        );
        assert_eq!(
            read_regular(&d, 100, "a test file").unwrap_err(),
            "it is a directory, not a regular file"
        );
        std::fs::write(d.join("f"), "abc").unwrap();
        std::os::unix::fs::symlink(d.join("f"), d.join("l")).unwrap();
        assert_eq!(read_text(&d.join("l"), 3, "a test file").unwrap(), "abc");
        let e = read_text(&d.join("l"), 2, "a test file").unwrap_err();
        assert_eq!(
            e,
            "it is 3 bytes, larger than 2 bytes, the limit for a test file"
        );
        let _ = std::fs::remove_dir_all(&d);
    }

    /// A file appended to after it was opened is cut at its cap with an error, not read on.
    #[test]
    fn a_file_growing_past_its_cap_fails_the_read() {
        let d = tmp("grow");
        let p = d.join("f");
        std::fs::write(&p, "ab").unwrap();
        let mut f = open_regular(&p, 4, "a test file").unwrap();
        std::fs::write(&p, "abcdefgh").unwrap();
        let mut s = String::new();
        let e = f.read_to_string(&mut s).unwrap_err();
        assert!(e.to_string().contains("larger than 4 bytes"), "{e}");
        let _ = std::fs::remove_dir_all(&d);
    }

    #[test]
    fn sizes_are_shown_in_whole_units() {
        assert_eq!(show_bytes(1 << 20), "1 MiB");
        assert_eq!(show_bytes(3 << 10), "3 KiB");
        assert_eq!(show_bytes(1000), "1000 bytes");
    }
}
