//! Regression: tick 0 of a realtime run missed its 150 µs budget in most runs, because iceoryx2
//! connects ports lazily, in the first send, receive or notify that notices a peer: the subscriber
//! mapped the publisher's data segment and the notifier opened the listener's socket inside tick 0.
//! `ipc::connect_now` (called at START) does that work before the loop. The guard used to be an
//! end-to-end "tick 0 was applied" check, which a busy host also breaks; this checks the cause
//! instead, deterministically: after `connect_now` the first exchange opens no file descriptor
//! and maps no memory, while without it the same exchange does both.
//!
//! One test in this binary: the harness runs tests on parallel threads, and another test's ports
//! would change the process's descriptors and mappings under this one.

use deltaloop_transport::ipc::{self, LOOP_BUFFER};
use deltaloop_transport::wire::StateMsg;

/// Open file descriptors and memory mappings of this process.
fn footprint() -> (usize, usize) {
    let fds = std::fs::read_dir("/proc/self/fd").unwrap().count();
    let maps = std::fs::read_to_string("/proc/self/maps")
        .unwrap()
        .lines()
        .count();
    (fds, maps)
}

/// Builds a plant → controller hand-off (state publisher and subscriber, `state-ready` notifier
/// and listener, each side on its own node), connects it now if asked, and returns the footprint
/// change of the first exchange: publish, notify, receive, take the event.
fn first_exchange_footprint_change(connect: bool) -> (isize, isize) {
    let run = format!("connect-now-{}-{connect}", std::process::id());
    let plant = ipc::node("plant", &run).unwrap();
    let ctrl = ipc::node("controller", &run).unwrap();
    let publisher = ipc::state(&plant, &run)
        .unwrap()
        .publisher("state publisher")
        .unwrap();
    let subscriber = ipc::state(&ctrl, &run)
        .unwrap()
        .subscriber(Some(LOOP_BUFFER), "state subscriber")
        .unwrap();
    let listener = ipc::listener(&ctrl, &run, "state-ready").unwrap();
    let notifier = ipc::notifier(&plant, &run, "state-ready").unwrap();
    if connect {
        ipc::connect_now(&[&publisher, &subscriber, &notifier]).unwrap();
    }
    let before = footprint();
    publisher
        .send_copy(StateMsg {
            tick: 7,
            ..StateMsg::default()
        })
        .unwrap();
    notifier.notify().unwrap();
    let got = subscriber.receive().unwrap().map(|s| s.tick);
    let woke = listener.try_wait().unwrap() > 0;
    let after = footprint();
    assert_eq!((got, woke), (Some(7), true), "connect = {connect}");
    (
        after.0 as isize - before.0 as isize,
        after.1 as isize - before.1 as isize,
    )
}

#[test]
fn regression_tick_0_missed_its_budget_connect_now_leaves_the_first_exchange_nothing_to_open() {
    let lazy = first_exchange_footprint_change(false);
    // The premise: left to itself, iceoryx2 connects inside the first exchange. If this ever
    // fails, iceoryx2 connects eagerly and `connect_now` may no longer be needed.
    assert!(
        lazy.0 > 0 || lazy.1 > 0,
        "without connect_now the first exchange opened and mapped nothing: {lazy:?}"
    );
    assert_eq!(
        first_exchange_footprint_change(true),
        (0, 0),
        "after connect_now the first exchange still opened descriptors or mapped memory \
         (descriptors, mappings)"
    );
}
