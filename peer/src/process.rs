//! What both `*_main` entry points share: the C arguments, the process's name, and no panic
//! across the boundary.

use std::ffi::{CStr, c_char, c_int};
use std::panic::{AssertUnwindSafe, catch_unwind};

use deltaloop_transport::exit::{self, EXIT_FAULT, EXIT_USAGE, ProcessEnd};

use crate::error::set_error;

/// Runs a `*_main` entry point: parses the arguments as `A` and calls `body` with them and the
/// process's name (argv[0]'s file name); returns the exit code. `body` returns how the process
/// ended, or `Err(why)` for a usage error of the caller (a null function). clap's own exits
/// (`--help`, a bad argument), the end's line on stderr and the last error are seen to here; a
/// panic is caught and reported as a fault.
///
/// # Safety
/// `argv` holds `argc` valid C strings (or is null).
pub(crate) unsafe fn main_of<A: clap::Parser>(
    argc: c_int,
    argv: *const *const c_char,
    body: impl FnOnce(A, &str) -> Result<anyhow::Result<ProcessEnd>, &'static str>,
) -> c_int {
    // SAFETY: as the caller promised.
    unsafe {
        catch_main(argc, argv, |words, name| {
            let args = match parse(words) {
                Ok(a) => a,
                Err(code) => return code,
            };
            match body(args, name) {
                Ok(end) => exit_code(name, end),
                Err(why) => usage(name, why),
            }
        })
    }
}

/// Runs `body` with the arguments as strings and the process's name (argv[0]'s file name), and
/// returns its exit code; a panic is caught and reported as a fault.
///
/// # Safety
/// `argv` holds `argc` valid C strings (or is null).
unsafe fn catch_main(
    argc: c_int,
    argv: *const *const c_char,
    body: impl FnOnce(&[String], &str) -> u8,
) -> c_int {
    let r = catch_unwind(AssertUnwindSafe(|| {
        // SAFETY: as the caller promised.
        let words = unsafe { args_of(argc, argv) };
        let name = words
            .first()
            .map(|w| w.rsplit('/').next().unwrap_or(w).to_string())
            .unwrap_or_else(|| "deltaloop-peer".into());
        body(&words, &name)
    }));
    c_int::from(r.unwrap_or_else(|_| {
        let why = "the library panicked (a bug: please report it)";
        set_error(why);
        eprintln!("deltaloop-peer: {why}");
        EXIT_FAULT
    }))
}

/// The parsed arguments, or the exit code after clap printed why not (0 for `--help`).
fn parse<A: clap::Parser>(words: &[String]) -> Result<A, u8> {
    A::try_parse_from(words).map_err(|e| {
        let _ = e.print();
        if e.use_stderr() {
            set_error(e.to_string().trim_end());
            EXIT_USAGE
        } else {
            0
        }
    })
}

/// A usage error of the caller (a null function): its line on stderr and in the last error.
fn usage(name: &str, why: &str) -> u8 {
    set_error(why);
    eprintln!("{name}: {why}");
    EXIT_USAGE
}

/// The exit code of how the process ended, having printed its one line on stderr and set it as
/// the last error (every end but completed).
fn exit_code(name: &str, end: anyhow::Result<ProcessEnd>) -> u8 {
    match &end {
        Ok(ProcessEnd::Completed) => {}
        Ok(ProcessEnd::Stopped(why) | ProcessEnd::Fault(why) | ProcessEnd::PeerSilent(why)) => {
            set_error(why)
        }
        Err(e) => set_error(&format!("{e:#}")),
    }
    exit::code(name, end)
}

/// The C arguments as strings (lossy UTF-8).
unsafe fn args_of(argc: c_int, argv: *const *const c_char) -> Vec<String> {
    if argv.is_null() {
        return Vec::new();
    }
    (0..usize::try_from(argc).unwrap_or(0))
        .filter_map(|i| {
            // SAFETY: argv holds argc pointers (the caller's promise).
            let p = unsafe { *argv.add(i) };
            // SAFETY: each non-null one is a C string.
            (!p.is_null()).then(|| unsafe { CStr::from_ptr(p) }.to_string_lossy().into_owned())
        })
        .collect()
}
