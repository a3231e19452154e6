//! A child's exit status in words (a leaf: the spawner and the fault classifier both use it).

use std::process::ExitStatus;

/// How a child ended, in words: a signal by its name, and SIGBUS with its likely cause.
pub(super) fn status_text(s: ExitStatus) -> String {
    use std::os::unix::process::ExitStatusExt;
    match (s.code(), s.signal()) {
        (_, Some(sig)) => killed_by(sig),
        (Some(101), _) => "panicked (exit status 101)".into(),
        (Some(c), _) => format!("exited with status {c}"),
        _ => "exited".into(),
    }
}

/// "was killed by SIGBUS (…)" for signal `sig`. A loop process touches nothing but its shared
/// memory mappings that could fault with SIGBUS: a page of a `/dev/shm` file that cannot be
/// backed because the file system is full.
pub(super) fn killed_by(sig: i32) -> String {
    let name = match sig {
        libc::SIGKILL => "SIGKILL",
        libc::SIGBUS => {
            return "was killed by SIGBUS (signal 7: a bus error, most likely shared memory (/dev/shm) ran out; see `df -h /dev/shm`)".into();
        }
        libc::SIGSEGV => "SIGSEGV",
        libc::SIGABRT => "SIGABRT",
        libc::SIGTERM => "SIGTERM",
        libc::SIGINT => "SIGINT",
        libc::SIGHUP => "SIGHUP",
        libc::SIGPIPE => "SIGPIPE",
        libc::SIGFPE => "SIGFPE",
        libc::SIGILL => "SIGILL",
        libc::SIGQUIT => "SIGQUIT",
        libc::SIGXCPU => "SIGXCPU",
        _ => return format!("was killed by signal {sig}"),
    };
    format!("was killed ({name})")
}
