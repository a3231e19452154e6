//! The run a peer's `init` (and a plant's `start`) reads: its resolved config, the law and the
//! mode, by dotted key.

use std::ffi::{CStr, CString, c_char, c_int};

use deltaloop_config::RunConfig;
use deltaloop_transport::args::LoopArgs;

use crate::error::{DL_BAD_ARGUMENT, DL_NOT_FOUND, DL_OK, DL_WRONG_TYPE, set_error};

/// The run as the process sees it before READY: its resolved config (every constant the built-in
/// processes use, from `[controller]`, `[plant]`, `[loop]`, `[sensor]`, …, defaults filled in),
/// the law and the mode. Opaque: read it with the `dl_run_*` functions, valid during `init` (and
/// a plant's `start`) only.
pub struct DlRun {
    config: toml::Table,
    /// The config itself, for the project's model (`dl_model_open`).
    pub(crate) cfg: RunConfig,
    law: CString,
    mode: CString,
    /// What `init` named the controller ([`dl_run_set_label`]).
    label: std::cell::RefCell<Option<String>>,
}

impl DlRun {
    /// The run of `cfg` (the one the process loaded from `args`), asked for law `law`.
    pub(crate) fn new(cfg: &RunConfig, args: &LoopArgs, law: &str) -> anyhow::Result<Self> {
        Ok(Self {
            config: toml::Table::try_from(cfg)?,
            cfg: cfg.clone(),
            law: CString::new(law)?,
            mode: CString::new(args.mode.name())?,
            label: std::cell::RefCell::new(None),
        })
    }

    /// What `init` named the controller, if it did.
    pub(crate) fn label(&self) -> Option<String> {
        self.label.borrow().clone()
    }

    /// The value at a dotted key (`controller.m_bar`).
    fn value(&self, key: &str) -> Option<&toml::Value> {
        let mut parts = key.split('.');
        let mut v = self.config.get(parts.next()?)?;
        for p in parts {
            v = v.as_table()?.get(p)?;
        }
        Some(v)
    }
}

/// The value at `key` of the run, as `pick` reads it (`what` names the type for the error), or
/// the error code (with its message in [`dl_last_error`](crate::dl_last_error)).
unsafe fn lookup<'a, T>(
    run: *const DlRun,
    key: *const c_char,
    what: &str,
    pick: impl FnOnce(&'a toml::Value) -> Option<T>,
) -> Result<T, c_int> {
    if run.is_null() || key.is_null() {
        set_error("a null run or key");
        return Err(DL_BAD_ARGUMENT);
    }
    // SAFETY: a run handed to init, and a C string (the caller's promise).
    let (run, key) = unsafe { (&*run, CStr::from_ptr(key)) };
    let Ok(key) = key.to_str() else {
        set_error("the key is not UTF-8");
        return Err(DL_BAD_ARGUMENT);
    };
    let Some(v) = run.value(key) else {
        set_error(&format!("the run's config has no key {key}"));
        return Err(DL_NOT_FOUND);
    };
    pick(v).ok_or_else(|| {
        set_error(&format!("{key} is not {what}"));
        DL_WRONG_TYPE
    })
}

/// Writes `v` to `out` (DL_OK), or DL_BAD_ARGUMENT if `out` is null (saying so in the last
/// error, as every error return does).
unsafe fn put<T>(out: *mut T, v: Result<T, c_int>) -> c_int {
    match v {
        Err(code) => code,
        Ok(_) if out.is_null() => {
            set_error("a null out pointer");
            DL_BAD_ARGUMENT
        }
        Ok(x) => {
            // SAFETY: non-null and writable (the caller's promise).
            unsafe { *out = x };
            DL_OK
        }
    }
}

/// The number at dotted `key` of the run's resolved config (`"controller.m_bar"`,
/// `"loop.ts_s"`; an integer reads as its value) into `*out`. DL_OK, DL_NOT_FOUND,
/// DL_WRONG_TYPE or DL_BAD_ARGUMENT.
///
/// # Safety
/// `run` is the one `init` got, `key` a C string, `out` writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn dl_run_f64(run: *const DlRun, key: *const c_char, out: *mut f64) -> c_int {
    // SAFETY: forwarded promises.
    unsafe {
        let v = lookup(run, key, "a number", |v| match v {
            toml::Value::Float(x) => Some(*x),
            toml::Value::Integer(i) => Some(*i as f64),
            _ => None,
        });
        put(out, v)
    }
}

/// The integer at dotted `key` (`"controller.tde_delay_samples"`) into `*out`; as
/// [`dl_run_f64`].
///
/// # Safety
/// As [`dl_run_f64`].
#[unsafe(no_mangle)]
pub unsafe extern "C" fn dl_run_i64(run: *const DlRun, key: *const c_char, out: *mut i64) -> c_int {
    // SAFETY: forwarded promises.
    unsafe { put(out, lookup(run, key, "an integer", toml::Value::as_integer)) }
}

/// The text at dotted `key` (`"sensor.velocity"`), NUL-terminated, into `buf` of `len` bytes.
/// Returns its length without the NUL, or DL_NOT_FOUND, DL_WRONG_TYPE, DL_BAD_ARGUMENT (also
/// when it does not fit).
///
/// # Safety
/// As [`dl_run_f64`]; `buf` holds `len` writable bytes.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn dl_run_str(
    run: *const DlRun,
    key: *const c_char,
    buf: *mut c_char,
    len: usize,
) -> c_int {
    // SAFETY: forwarded promises.
    let s = match unsafe { lookup(run, key, "text", toml::Value::as_str) } {
        Ok(s) => s,
        Err(code) => return code,
    };
    if buf.is_null() {
        set_error("a null buffer");
        return DL_BAD_ARGUMENT;
    }
    let Ok(n) = c_int::try_from(s.len()) else {
        set_error(&format!(
            "the text is {} bytes, more than an int counts",
            s.len()
        ));
        return DL_BAD_ARGUMENT;
    };
    if s.len() >= len {
        set_error(&format!(
            "the buffer is too small: {len} bytes for {} bytes and the NUL",
            s.len()
        ));
        return DL_BAD_ARGUMENT;
    }
    // SAFETY: buf holds len > s.len() bytes.
    unsafe {
        std::ptr::copy_nonoverlapping(s.as_ptr(), buf.cast(), s.len());
        *buf.add(s.len()) = 0;
    }
    n
}

/// The longest controller label, characters (what the run shows).
const LABEL_CHARS: usize = 64;
/// The longest controller label, bytes of UTF-8: what the READY message's text carries.
const LABEL_BYTES: usize = 160;

/// Names the controller (from `init`): the run shows `label` beside the law it answers as, in
/// the terminal table, `summary.json` (`controller_label`) and `report.md`, unless the run was
/// given one (`--controller-label`, `controller.label`); without either it shows the command's
/// program name. One line of at most 64 printable characters and 160 bytes of UTF-8. DL_OK, or
/// DL_BAD_ARGUMENT (a null pointer, or a label that is not one such line).
///
/// # Safety
/// `run` is the one `init` got, `label` a C string.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn dl_run_set_label(run: *const DlRun, label: *const c_char) -> c_int {
    if run.is_null() || label.is_null() {
        set_error("dl_run_set_label: a null run or label");
        return DL_BAD_ARGUMENT;
    }
    // SAFETY: a run handed to init, and a C string (the caller's promise).
    let (run, label) = unsafe { (&*run, CStr::from_ptr(label)) };
    let Ok(label) = label.to_str() else {
        set_error("dl_run_set_label: the label is not UTF-8");
        return DL_BAD_ARGUMENT;
    };
    let n = label.chars().count();
    if n == 0 || n > LABEL_CHARS || label.len() > LABEL_BYTES || label.chars().any(char::is_control)
    {
        set_error(&format!(
            "dl_run_set_label: {label:?} is not one line of 1 to {LABEL_CHARS} printable characters and at most {LABEL_BYTES} bytes"
        ));
        return DL_BAD_ARGUMENT;
    }
    *run.label.borrow_mut() = Some(label.to_string());
    DL_OK
}

/// The law the run asks for (`--law`: "tdc", "tdc-is-sta", …; "" if none was given; "" and the
/// last error set for a null run).
///
/// # Safety
/// `run` is null or the one `init` got.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn dl_run_law(run: *const DlRun) -> *const c_char {
    // SAFETY: the caller's promise.
    unsafe { run.as_ref() }.map_or_else(|| null_run("dl_run_law"), |r| r.law.as_ptr())
}

/// The loop mode: "lockstep" or "realtime" ("" and the last error set for a null run).
///
/// # Safety
/// `run` is null or the one `init` got.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn dl_run_mode(run: *const DlRun) -> *const c_char {
    // SAFETY: the caller's promise.
    unsafe { run.as_ref() }.map_or_else(|| null_run("dl_run_mode"), |r| r.mode.as_ptr())
}

/// The empty text a getter returns for a null run, having said so in the last error.
fn null_run(function: &str) -> *const c_char {
    set_error(&format!("{function}: a null run"));
    c"".as_ptr()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dl_last_error;

    /// Regression: a label of 64 characters could take 256 bytes of UTF-8, and the READY text
    /// that carries it holds 160: the run showed it cut. Such a label is refused, whole.
    #[test]
    fn regression_a_label_longer_than_the_ready_text_is_refused() {
        let cfg =
            RunConfig::from_toml_str("name = \"t\"\n[scenario]\npath = \"s1\"\n", None).unwrap();
        let args = LoopArgs {
            run_id: "r".into(),
            config: "c.toml".into(),
            mode: deltaloop_config::LoopMode::Lockstep,
        };
        let run = DlRun::new(&cfg, &args, "tdc").unwrap();
        let set = |label: &str| {
            let c = std::ffi::CString::new(label).unwrap();
            // SAFETY: a live run and C string.
            unsafe { dl_run_set_label(&run, c.as_ptr()) }
        };
        assert_eq!(set(&"é".repeat(64)), DL_OK, "64 characters, 128 bytes");
        assert_eq!(run.label().as_deref(), Some("é".repeat(64).as_str()));
        assert_eq!(
            set(&"€".repeat(60)),
            DL_BAD_ARGUMENT,
            "60 characters, 180 bytes"
        );
        assert_eq!(set(&"x".repeat(65)), DL_BAD_ARGUMENT);
        assert_eq!(
            run.label().as_deref(),
            Some("é".repeat(64).as_str()),
            "kept"
        );
    }

    /// A run's constants read back by key and type, and each error code where it belongs.
    #[test]
    fn run_constants_read_by_key_with_their_error_codes() {
        let cfg = RunConfig::from_toml_str(
            "name = \"t\"\n[scenario]\npath = \"s1\"\n[controller]\nm_bar = 0.03\ntde_delay_samples = 1\n",
            None,
        )
        .unwrap();
        let args = LoopArgs {
            run_id: "r".into(),
            config: "c.toml".into(),
            mode: deltaloop_config::LoopMode::Lockstep,
        };
        let run = DlRun::new(&cfg, &args, "tdc").unwrap();
        let (mut x, mut i, mut buf) = (0.0, 0i64, [0 as c_char; 16]);
        // SAFETY: live values of the right types.
        unsafe {
            assert_eq!(
                dl_run_f64(&run, c"controller.m_bar".as_ptr(), &mut x),
                DL_OK
            );
            assert_eq!(x, 0.03);
            assert_eq!(
                dl_run_f64(&run, c"controller.tde_delay_samples".as_ptr(), &mut x),
                DL_OK
            );
            assert_eq!(x, 1.0);
            // Resolved: a default the file does not set reads as the process uses it.
            assert_eq!(dl_run_f64(&run, c"loop.ts_s".as_ptr(), &mut x), DL_OK);
            assert_eq!(x, cfg.loop_.ts_s);
            assert_eq!(
                dl_run_i64(&run, c"controller.tde_delay_samples".as_ptr(), &mut i),
                DL_OK
            );
            assert_eq!(i, 1);
            assert_eq!(
                dl_run_i64(&run, c"controller.m_bar".as_ptr(), &mut i),
                DL_WRONG_TYPE
            );
            assert_eq!(
                dl_run_f64(&run, c"controller.no_such_key".as_ptr(), &mut x),
                DL_NOT_FOUND
            );
            assert!(
                CStr::from_ptr(dl_last_error())
                    .to_str()
                    .unwrap()
                    .contains("controller.no_such_key")
            );
            assert_eq!(
                dl_run_str(&run, c"sensor.velocity".as_ptr(), buf.as_mut_ptr(), 16),
                8
            );
            assert_eq!(CStr::from_ptr(buf.as_ptr()).to_str().unwrap(), "measured");
            assert_eq!(
                dl_run_str(&run, c"sensor.velocity".as_ptr(), buf.as_mut_ptr(), 8),
                DL_BAD_ARGUMENT
            );
            assert_eq!(
                dl_run_f64(std::ptr::null(), c"x".as_ptr(), &mut x),
                DL_BAD_ARGUMENT
            );
            assert_eq!(CStr::from_ptr(dl_run_law(&run)).to_str().unwrap(), "tdc");
            assert_eq!(
                CStr::from_ptr(dl_run_mode(&run)).to_str().unwrap(),
                "lockstep"
            );
        }
    }
}
