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
fn killed_by(sig: i32) -> String {
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

#[cfg(test)]
mod tests {
    use super::*;

    /// Regression: a full /dev/shm mid-run killed the plant with a bare "signal 7".
    #[test]
    fn regression_a_child_killed_by_sigbus_is_named_with_its_likely_cause() {
        let bus = killed_by(libc::SIGBUS);
        assert!(
            bus.starts_with("was killed by SIGBUS")
                && bus.contains("shared memory (/dev/shm) ran out"),
            "{bus}"
        );
        assert_eq!(killed_by(libc::SIGKILL), "was killed (SIGKILL)");
        assert_eq!(killed_by(libc::SIGSEGV), "was killed (SIGSEGV)");
        assert_eq!(killed_by(64), "was killed by signal 64");
    }
}
