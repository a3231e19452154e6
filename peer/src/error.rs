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

thread_local! {
    static LAST_ERROR: std::cell::RefCell<CString> = std::cell::RefCell::new(CString::default());
}

pub(crate) fn set_error(msg: &str) {
    let c = CString::new(msg.replace('\0', " ")).unwrap_or_default();
    LAST_ERROR.with(|e| *e.borrow_mut() = c);
}

/// The message of the last failed call on this thread (empty if none); valid until the next call.
#[unsafe(no_mangle)]
pub extern "C" fn dl_last_error() -> *const c_char {
    LAST_ERROR.with(|e| e.borrow().as_ptr())
}

/// Sets this thread's error message: a callback that fails says why here, and the process's one
/// line on stderr quotes it. `msg` may be null (clears it).
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
