//! A user's controller (Python, C) joining from the other host.

use super::*;

#[test]
fn a_python_controller_joins_from_the_other_host() {
    // The venv first: a first run installs it, and the other netns tests need not wait for that.
    let py = common::python::python().display().to_string();
    let Some((h, _one)) = Hosts::new("a_python_controller_joins_from_the_other_host") else {
        return;
    };
    let cmd = format!("{py} examples/python-controller/controller.py");
    let log = assert_lockstep_identical(&h, &[], &["--controller-cmd", &cmd]);
    // It speaks only iceoryx2: its bridge relays it, while the plant's side goes direct (the
    // far bridge then copies each reply for the record there).
    assert!(!far_went_direct(&log), "{log}");
    assert!(
        log.contains("far side: this side relays the controller here"),
        "{log}"
    );
    assert!(
        log.contains("the plant here took the link's socket"),
        "{log}"
    );
}

/// The C `tdc` controller (the C ABI, examples/c-controller) joins from the other host: lockstep
/// across the link is byte-identical to inproc.
#[test]
fn a_c_controller_joins_from_the_other_host() {
    // Built before the namespaces are taken (see the Python controller's test).
    let Some(exe) = common::c_tdc() else { return };
    let Some((h, _one)) = Hosts::new("a_c_controller_joins_from_the_other_host") else {
        return;
    };
    let log = assert_lockstep_identical(&h, &[], &["--controller-cmd", exe.to_str().unwrap()]);
    // Through the C ABI it takes the link's socket like the built-in one: no relay on its path.
    assert!(far_went_direct(&log), "{log}");
    assert!(
        log.contains("the plant here took the link's socket"),
        "{log}"
    );
}
