//! Return codes and the calling thread's last error message.

use std::ffi::{CStr, CString, c_char, c_int};

/// Success.
pub const DL_OK: c_int = 0;
/// The key is not in the run's config.
pub const DL_NOT_FOUND: c_int = -1;
/// The key holds another type (a table, text where a number was asked, …).
pub const DL_WRONG_TYPE: c_int = -2;
/// A null pointer, a key that is not UTF-8, a buffer too small, or a value out of range.
pub const DL_BAD_ARGUMENT: c_int = -3;
/// The longest error message kept, in bytes (without the NUL): a longer one is cut at a character
/// boundary and ends with " …[cut]".
pub const DL_ERROR_MAX_BYTES: usize = 512;

/// What ends a message that was cut to [`DL_ERROR_MAX_BYTES`].
const CUT_MARK: &str = " …[cut]";

thread_local! {
    static LAST_ERROR: std::cell::RefCell<CString> = std::cell::RefCell::new(CString::default());
}

/// Sets this thread's last error to `msg` as one bounded line (see [`one_line`]).
pub(crate) fn set_error(msg: &str) {
    let c = CString::new(one_line(msg)).unwrap_or_default();
    LAST_ERROR.with(|e| *e.borrow_mut() = c);
}

/// `msg` as one line of inert text of at most [`DL_ERROR_MAX_BYTES`] bytes: control and hidden
/// characters escaped (`\n`, `\u{1b}`, NUL too), cut at a character boundary with [`CUT_MARK`].
/// A peer's message ends up in the run's log, whose last line is the run's reason: a newline
/// would hide it, an escape code would drive the reader's terminal, and a megabyte would push the
/// whole line out of the part of the log that is read.
fn one_line(msg: &str) -> String {
    let room = DL_ERROR_MAX_BYTES - CUT_MARK.len();
    let mut out = String::with_capacity(msg.len().min(DL_ERROR_MAX_BYTES));
    // The length of `out` at the last character boundary within `room`.
    let mut fits = 0;
    let mut buf = [0u8; 4];
    for c in msg.chars() {
        let piece = deltaloop_wire::escape_peer_text(c.encode_utf8(&mut buf));
        if out.len() + piece.len() > DL_ERROR_MAX_BYTES {
            out.truncate(fits);
            out.push_str(CUT_MARK);
            return out;
        }
        out.push_str(&piece);
        if out.len() <= room {
            fits = out.len();
        }
    }
    out
}

/// The message of the last failed call on this thread (empty if none); valid until the next call.
/// Every function of this library that returns an error code, or a non-zero exit code, sets it
/// first. One line, at most [`DL_ERROR_MAX_BYTES`] bytes.
#[unsafe(no_mangle)]
pub extern "C" fn dl_last_error() -> *const c_char {
    LAST_ERROR.with(|e| e.borrow().as_ptr())
}

/// Sets this thread's error message: a callback that fails says why here, and the process's one
/// line on stderr quotes it. `msg` may be null (clears it). Kept as one line of at most
/// [`DL_ERROR_MAX_BYTES`] bytes: control characters (newlines, escape codes) are written as
/// escapes (`\n`, `\u{1b}`), and a longer message is cut at a character boundary, ending in
/// " …[cut]".
///
/// # Safety
/// `msg` is null or a C string.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn dl_set_error(msg: *const c_char) {
    let text = if msg.is_null() {
        String::new()
    } else {
        // SAFETY: a non-null C string (the caller's promise).
        unsafe { CStr::from_ptr(msg) }
            .to_string_lossy()
            .into_owned()
    };
    set_error(&text);
}

/// This thread's error message, taken (empty: none).
fn take_error() -> String {
    LAST_ERROR
        .with(|e| std::mem::take(&mut *e.borrow_mut()))
        .to_string_lossy()
        .into_owned()
}

/// What a failed callback said: `(it returned rc)`, and its message if it set one.
pub(crate) fn refusal(rc: c_int) -> String {
    match take_error() {
        m if m.is_empty() => format!("it returned {rc}"),
        m => format!("{m} (it returned {rc})"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn last() -> String {
        // SAFETY: dl_last_error always returns a C string.
        unsafe { CStr::from_ptr(dl_last_error()) }
            .to_str()
            .unwrap()
            .to_string()
    }

    /// Regression: a callback's message went out raw: escape codes reached the reader's terminal,
    /// a newline left the run with only the message's last line, and a 1 MiB message pushed the
    /// reason out of the part of the log the supervisor reads. Now it is one line, escaped, and
    /// at most DL_ERROR_MAX_BYTES bytes, cut at a character boundary with a mark.
    #[test]
    fn regression_error_text_is_one_escaped_bounded_line() {
        // SAFETY: C strings.
        unsafe { dl_set_error(c"\x1b[31mred\nsecond line\r\x07".as_ptr()) };
        assert_eq!(last(), "\\u{1b}[31mred\\nsecond line\\r\\u{7}");
        let huge = CString::new("é".repeat(512 * 1024)).unwrap(); // 1 MiB, two bytes a char
        // SAFETY: a C string.
        unsafe { dl_set_error(huge.as_ptr()) };
        let m = last();
        assert!(m.len() <= DL_ERROR_MAX_BYTES, "{} bytes", m.len());
        assert!(m.ends_with(CUT_MARK), "{m}");
        assert!(m.trim_end_matches(CUT_MARK).chars().all(|c| c == 'é'));
        // Cut between escapes, never inside one.
        let esc = CString::new("\n".repeat(1000)).unwrap();
        // SAFETY: a C string.
        unsafe { dl_set_error(esc.as_ptr()) };
        let m = last();
        assert!(
            m.trim_end_matches(CUT_MARK).split("\\n").all(str::is_empty),
            "{m}"
        );
        // A message that fits is kept whole, without a mark.
        let fits = "x".repeat(DL_ERROR_MAX_BYTES);
        set_error(&fits);
        assert_eq!(last(), fits);
        set_error(&format!("{fits}y"));
        assert!(last().ends_with(CUT_MARK));
        // SAFETY: null clears it.
        unsafe { dl_set_error(std::ptr::null()) };
        assert_eq!(last(), "");
    }
}
