//! Text a peer wrote (a child's stderr, the reason a child gives) made safe to show on a terminal
//! and to store in `summary.json` and `report.md`: decoded lossily (one bad byte does not blank
//! the line), control characters escaped (a peer's escape codes never reach the terminal), one
//! line, cut to a bounded length that says where it was cut. Logs are read from their end with a
//! bounded read, so a child that printed 20 MB costs 64 KiB.

use deltaloop_transport::wire::escape_peer_text;
use std::fmt::Write as _;
use std::io::{Read, Seek, SeekFrom};
use std::path::Path;

/// The longest line quoted from a peer, characters (after escaping), before the cut note: room
/// for the plant's own longest reasons (≈ 300), not for a flood.
pub const MAX_CHARS: usize = 1000;

/// How much of a log's end is read, bytes.
pub const TAIL_BYTES: u64 = 64 * 1024;

/// How many lines of each child's log are echoed after a run.
pub const MAX_LINES: usize = 20;

/// `raw` as one printable line of at most `max_chars` characters plus a note saying where it was
/// cut: decoded lossily (invalid UTF-8 becomes U+FFFD), every control character escaped (`\n`,
/// `\t`, `\u{1b}`), leading and trailing blanks trimmed.
pub fn sanitize(raw: &[u8], max_chars: usize) -> String {
    let text = String::from_utf8_lossy(raw);
    let text = text.trim();
    let total = text.chars().count();
    let mut out = String::new();
    let (mut used, mut shown) = (0usize, 0usize);
    for c in text.chars() {
        // The escaping rule is the transport's, the one `ControlMsg::text` applies.
        let piece = escape_peer_text(c.encode_utf8(&mut [0; 4]));
        let n = piece.chars().count();
        if used + n > max_chars {
            let _ = write!(out, " … [cut after {shown} of {total} characters]");
            return out;
        }
        out.push_str(&piece);
        used += n;
        shown += 1;
    }
    out
}

/// Whether a log line is noise when looking for why a child stopped: warnings, backtrace frames,
/// notes.
fn noise(l: &str) -> bool {
    let t = l.trim_start();
    l.contains("warning:")
        || t.starts_with("at ")
        || t.starts_with(|c: char| c.is_ascii_digit())
        || l.starts_with("note:")
        || l.starts_with("stack backtrace")
}

/// The line that says why a child stopped, from its log's lines (raw bytes, oldest first): a
/// panic's message (the panic line and the one after), else the last line that is not noise;
/// sanitized. "" if there is none.
pub fn reason(lines: &[&[u8]]) -> String {
    let text: Vec<String> = lines
        .iter()
        .map(|l| String::from_utf8_lossy(l).into_owned())
        .filter(|l| !l.trim().is_empty())
        .collect();
    if let Some(i) = text.iter().rposition(|l| l.contains("panicked at")) {
        let both = format!(
            "{} {}",
            text[i].trim(),
            text.get(i + 1).map_or("", |l| l.trim())
        );
        return sanitize(both.as_bytes(), MAX_CHARS);
    }
    text.iter()
        .rev()
        .find(|l| !noise(l))
        .map_or_else(String::new, |l| sanitize(l.as_bytes(), MAX_CHARS))
}

/// The end of a log: its last [`TAIL_BYTES`] at most, split into lines (the first, partial line
/// of a cut read dropped), and whether earlier text was left unread.
pub struct Tail {
    pub lines: Vec<Vec<u8>>,
    pub earlier: bool,
}

impl Tail {
    /// Reads the end of `path` (an unreadable or missing log is empty).
    pub fn read(path: &Path) -> Self {
        Self::read_bytes(path, TAIL_BYTES).unwrap_or(Tail {
            lines: Vec::new(),
            earlier: false,
        })
    }

    fn read_bytes(path: &Path, max: u64) -> std::io::Result<Self> {
        // Only a regular file, opened without blocking: a log replaced by a FIFO must not hang
        // the supervisor (anything else reads as an empty log).
        let Ok(mut f) = deltaloop_config::files::open_regular_file(path) else {
            return Ok(Tail {
                lines: Vec::new(),
                earlier: false,
            });
        };
        let len = f.metadata()?.len();
        let from = len.saturating_sub(max);
        f.seek(SeekFrom::Start(from))?;
        let mut buf = Vec::new();
        f.take(max).read_to_end(&mut buf)?;
        let mut lines: Vec<Vec<u8>> = buf.split(|&b| b == b'\n').map(<[u8]>::to_vec).collect();
        if from > 0 && !lines.is_empty() {
            lines.remove(0);
        }
        lines.retain(|l| !String::from_utf8_lossy(l).trim().is_empty());
        Ok(Tail {
            lines,
            earlier: from > 0,
        })
    }

    /// Why the child stopped: see [`reason`].
    pub fn reason(&self) -> String {
        let lines: Vec<&[u8]> = self.lines.iter().map(Vec::as_slice).collect();
        reason(&lines)
    }

    /// Its last `max` lines, sanitized; when more came before, a first line says where they are.
    pub fn last_lines(&self, max: usize, path: &Path) -> Vec<String> {
        let skip = self.lines.len().saturating_sub(max);
        let mut out = Vec::new();
        if skip > 0 || self.earlier {
            out.push(format!(
                "(earlier lines of {} not shown{})",
                path.display(),
                if self.earlier {
                    String::new()
                } else {
                    format!(": {skip}")
                }
            ));
        }
        out.extend(self.lines[skip..].iter().map(|l| sanitize(l, MAX_CHARS)));
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// Regression: one byte of invalid UTF-8 in a child's stderr blanked the quoted reason.
    #[test]
    fn regression_a_non_utf8_byte_does_not_blank_the_reason() {
        let lines: [&[u8]; 2] = [b"starting", b"error: bad value \xff in frame"];
        assert_eq!(reason(&lines), "error: bad value \u{fffd} in frame");
    }

    /// Regression: a peer's escape codes (clear screen, a newline) reached the terminal.
    #[test]
    fn regression_escape_codes_and_newlines_are_escaped() {
        let s = sanitize(b"\x1b[2J\x1b[Hgone\r\nnext\tcol \x7f \xc2\x9b", MAX_CHARS);
        assert_eq!(s, "\\u{1b}[2J\\u{1b}[Hgone\\r\\nnext\\tcol \\u{7f} \\u{9b}");
        assert_eq!(sanitize("a\u{202e}b".as_bytes(), 50), "a\\u{202e}b");
    }

    /// Regression: a 20 MB line became a 20 MB "one-line" error.
    #[test]
    fn regression_a_long_line_is_cut_and_says_where() {
        let long = "x".repeat(20_000);
        let s = sanitize(long.as_bytes(), 10);
        assert_eq!(s, "xxxxxxxxxx … [cut after 10 of 20000 characters]");
        // An escape is never split.
        assert_eq!(
            sanitize(b"abcdefgh\x1b", 10),
            "abcdefgh … [cut after 8 of 9 characters]"
        );
    }

    #[test]
    fn the_reason_prefers_a_panic_and_skips_noise() {
        let lines: [&[u8]; 5] = [
            b"thread 'main' panicked at src/x.rs:3:5:",
            b"boom",
            b"note: run with `RUST_BACKTRACE=1`",
            b"warning: late",
            b"",
        ];
        assert_eq!(
            reason(&lines),
            "thread 'main' panicked at src/x.rs:3:5: boom"
        );
        let lines: [&[u8]; 3] = [
            b"deltaloop-plant: cannot open",
            b"   0: frame",
            b"warning: x",
        ];
        assert_eq!(reason(&lines), "deltaloop-plant: cannot open");
        assert_eq!(reason(&[]), "");
    }

    /// Regression: the whole log was read into memory and echoed; now its end only, bounded.
    #[test]
    fn regression_a_log_of_20000_lines_is_read_from_its_end_bounded() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("c.log");
        let mut text = String::new();
        for i in 0..20_000 {
            text.push_str(&format!("line {i} of a chatty child\n"));
        }
        text.push_str("fatal: the last word\n\n");
        std::fs::write(&p, &text).unwrap();
        let t = Tail::read(&p);
        assert!(t.earlier);
        assert!(t.lines.iter().map(Vec::len).sum::<usize>() <= TAIL_BYTES as usize);
        assert_eq!(t.reason(), "fatal: the last word");
        let shown = t.last_lines(3, &p);
        assert_eq!(shown.len(), 4, "{shown:?}");
        assert!(shown[0].starts_with("(earlier lines of "), "{shown:?}");
        assert_eq!(shown[3], "fatal: the last word");
        // A short log is shown whole; a missing one is empty.
        std::fs::write(&p, "one\ntwo\n").unwrap();
        assert_eq!(Tail::read(&p).last_lines(3, &p), ["one", "two"]);
        assert!(Tail::read(&dir.path().join("none")).lines.is_empty());
        // A FIFO in its place is not waited on.
        let fifo = dir.path().join("fifo.log");
        let c = std::ffi::CString::new(fifo.as_os_str().as_encoded_bytes()).unwrap();
        // SAFETY: a valid C string; creates a FIFO in our temporary folder.
        assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
        assert!(Tail::read(&fifo).lines.is_empty());
    }

    proptest! {
        /// Whatever bytes a peer writes: no control character comes out, the line is bounded,
        /// and it is valid UTF-8 (it round-trips through bytes).
        #[test]
        fn sanitized_text_is_printable_bounded_utf8(
            raw in proptest::collection::vec(any::<u8>(), 0..2000),
            max in 0usize..400,
        ) {
            let s = sanitize(&raw, max);
            // Nothing left that the escaping rule would touch.
            prop_assert_eq!(&escape_peer_text(&s), &s);
            let note = " … [cut after 2000 of 2000 characters]".chars().count();
            prop_assert!(s.chars().count() <= max + note, "{} > {max}", s.chars().count());
            prop_assert_eq!(String::from_utf8(s.clone().into_bytes()).unwrap(), s);
        }

        /// Text without control characters that fits is kept as it is (trimmed).
        #[test]
        fn plain_text_that_fits_is_unchanged(s in "[a-zA-Z0-9 :.,éµ→]{0,100}") {
            prop_assert_eq!(sanitize(s.as_bytes(), 400), s.trim());
        }
    }
}
