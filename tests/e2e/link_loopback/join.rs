//! Who may join: strangers and wrong keys refused, `join` trying again, stopping and cleaning up
//! after itself, and the far process never given the link key.

use super::*;

/// A connection to `ep` once something listens there (the near bridge, after set-up).
fn connect_when_listening(ep: &str) -> std::net::TcpStream {
    let t0 = std::time::Instant::now();
    loop {
        if let Ok(s) = std::net::TcpStream::connect(ep) {
            return s;
        }
        assert!(
            t0.elapsed() < Duration::from_secs(30),
            "nothing listens at {ep}"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// Everything a connection receives until the other side closes it (or 8 s pass).
fn all_it_hears(mut s: std::net::TcpStream) -> Vec<u8> {
    use std::io::Read;
    s.set_read_timeout(Some(Duration::from_secs(8))).unwrap();
    let mut got = Vec::new();
    let _ = s.read_to_end(&mut got);
    got
}

/// The link's mutual authentication, from the outside: a stranger who connects first to a
/// waiting `run --controller-remote --link-key` (and one who connects and stays silent) learns
/// nothing of the run and cannot be its controller; a `join` with another key is refused in one
/// line on both sides within seconds; the honest `join` that comes after them completes the run,
/// its trace byte-identical to in-process, and the run records whom it refused.
#[test]
fn strangers_and_wrong_keys_are_refused_and_the_honest_join_runs_byte_identical() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let (tmp, cfg, key, ep) = s1_with_key();
    let other = tmp.path().join("other.key");
    deltaloop_bridge::seal::LinkKey::write_new(&other).unwrap();
    let remote = tmp.path().join("remote");
    let run = common::spawn(&remote_lockstep(&cfg, &ep, &key, &remote));
    // A stranger first: a handshake-shaped message of junk. Then one that says nothing at all
    // and holds its connection while the others come.
    let mut stranger = connect_when_listening(&ep);
    let silent = connect_when_listening(&ep);
    std::io::Write::write_all(
        &mut stranger,
        &[&48u16.to_le_bytes()[..], &[7u8; 48]].concat(),
    )
    .unwrap();
    let heard = all_it_hears(stranger);
    assert!(
        heard.is_empty(),
        "the stranger was told {} bytes",
        heard.len()
    );
    // A join with another key: the near side says it refused the key, and the join names the
    // key at once (it does not take the refusal for a busy near side and wait out --wait-s).
    let t0 = std::time::Instant::now();
    let wrong = Command::new(env!("CARGO_BIN_EXE_deltaloop"))
        .args(["join", &ep, "--role", "controller", "--wait-s", "60"])
        .args(["--link-key", other.to_str().unwrap()])
        .env("DELTALOOP_IOX2_ROOT", tmp.path().join("root-wrong"))
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let w = common::finish_within(wrong, Duration::from_secs(30), "join with another key");
    assert!(t0.elapsed() < Duration::from_secs(10), "{:?}", t0.elapsed());
    assert_eq!(w.status.code(), Some(3));
    let said = text(&w.stderr);
    assert!(
        said.contains("does not hold this link key") && !said.contains("trying again"),
        "{said}"
    );
    // The honest side, last: the run completes as if the others had never been there.
    let far_root = tmp.path().join("far-root");
    let honest = join_with(&ep, &key, &far_root);
    let o = common::finish_within(run, Duration::from_secs(120), "deltaloop run");
    let j = common::finish_within(honest, Duration::from_secs(30), "honest join");
    drop(silent);
    deltaloop_supervisor::ops::loopback::remove_root(&far_root, false);
    assert!(o.status.success(), "{}", text(&o.stderr));
    assert!(j.status.success(), "join: {}", text(&j.stderr));
    let local = tmp.path().join("local");
    common::run(cfg.to_str().unwrap(), "inproc", &local, &[]);
    assert!(
        std::fs::read(remote.join("trace.csv")).unwrap()
            == std::fs::read(local.join("trace.csv")).unwrap(),
        "trace.csv across the sealed link differs from inproc"
    );
    let s = summary(&remote);
    // The built-in controller on the far host, not a foreign one (nor the near bridge).
    assert!(s.get("controller_label").is_none(), "{s}");
    let sec = &s["timing"]["tdc"]["link_security"];
    let fp = deltaloop_bridge::seal::LinkKey::read(&key)
        .unwrap()
        .fingerprint();
    assert_eq!(sec["key_fingerprint"], fp.as_str(), "{sec}");
    assert!(
        sec["peer"].as_str().unwrap().starts_with("127.0.0.1:"),
        "{sec}"
    );
    // The stranger and the wrong key at least (the silent one, if its 2 s ran out first).
    assert!(sec["refused_connections"].as_u64().unwrap() >= 2, "{sec}");
    assert_eq!(sec["refused_datagrams"]["forged"], 0, "{sec}");
    let log = std::fs::read_to_string(remote.join("tdc.controller.log")).unwrap();
    assert!(log.contains("failed authentication"), "{log}");
    let report = std::fs::read_to_string(remote.join("report.md")).unwrap();
    assert!(
        report.contains(&format!("joined with link key {fp}")),
        "{report}"
    );
    assert!(
        !report.contains(
            &deltaloop_bridge::seal::LinkKey::read(&key)
                .unwrap()
                .to_hex()
        )
    );
    assert!(
        !text(&o.stderr).contains(
            &deltaloop_bridge::seal::LinkKey::read(&key)
                .unwrap()
                .to_hex()
        )
    );
}

/// A `join --runs N` waiting at a listener of this test (the near side), with its own root.
fn join_runs(port: u16, key: &Path, runs: u32, root: &Path) -> std::process::Child {
    Command::new(env!("CARGO_BIN_EXE_deltaloop"))
        .args(["join", &format!("127.0.0.1:{port}"), "--role", "controller"])
        .args(["--runs", &runs.to_string(), "--wait-s", "60"])
        .args(["--link-key", key.to_str().unwrap()])
        .env("DELTALOOP_IOX2_ROOT", root)
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap()
}

/// The next connection to `l`, within 30 s.
fn accept_within(l: &std::net::TcpListener) -> std::net::TcpStream {
    l.set_nonblocking(true).unwrap();
    let t0 = std::time::Instant::now();
    loop {
        match l.accept() {
            Ok((s, _)) => {
                s.set_nonblocking(false).unwrap();
                return s;
            }
            Err(_) if t0.elapsed() < Duration::from_secs(30) => {
                std::thread::sleep(Duration::from_millis(10))
            }
            Err(e) => panic!("nobody connected within 30 s: {e}"),
        }
    }
}

/// SIGTERM to `child`, then its output within 5 s and how long that took.
fn terminate(child: std::process::Child) -> (std::process::Output, Duration) {
    let t0 = std::time::Instant::now();
    // SAFETY: our own child, not yet reaped.
    unsafe { libc::kill(child.id() as i32, libc::SIGTERM) };
    let o = common::finish_within(child, Duration::from_secs(10), "deltaloop join");
    (o, t0.elapsed())
}

/// Regression: a `join` whose near side authenticated and then said nothing ignored SIGINT and
/// SIGTERM for 28 s; it now stops at once, exit 5, saying what it was waiting for.
#[test]
fn regression_join_stops_on_sigterm_while_the_near_side_is_silent() {
    let tmp = tempfile::tempdir().unwrap();
    let key = tmp.path().join("link.key");
    let k = deltaloop_bridge::seal::LinkKey::write_new(&key).unwrap();
    let l = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let port = l.local_addr().unwrap().port();
    let root = tmp.path().join("far-root");
    let join = join_runs(port, &key, 1, &root);
    let mut s = accept_within(&l);
    let session = deltaloop_bridge::seal::Session::generate().unwrap();
    deltaloop_bridge::seal::respond(&mut s, &k, &session, Duration::from_secs(10)).unwrap();
    // Authenticated, and then no HELLO: the join waits for it.
    std::thread::sleep(Duration::from_millis(500));
    let (o, took) = terminate(join);
    drop(s);
    deltaloop_supervisor::ops::loopback::remove_root(&root, false);
    let err = text(&o.stderr);
    assert!(took < Duration::from_secs(3), "{took:?}: {err}");
    assert_eq!(o.status.code(), Some(5), "{err}");
    assert!(err.contains("waiting for the near side's HELLO"), "{err}");
}

/// Regression: `join --runs 0` exited when a connector closed at once (or a second join raced
/// it); it keeps serving: it connects again after each, until it is stopped.
#[test]
fn regression_join_runs_0_keeps_serving_after_a_connection_closed_at_once() {
    let tmp = tempfile::tempdir().unwrap();
    let key = tmp.path().join("link.key");
    deltaloop_bridge::seal::LinkKey::write_new(&key).unwrap();
    let l = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let port = l.local_addr().unwrap().port();
    let root = tmp.path().join("far-root");
    let mut join = join_runs(port, &key, 0, &root);
    for _ in 0..2 {
        drop(accept_within(&l));
    }
    // Still serving: it comes back a third time (within the same run's join, as a near side
    // that closed a connection in the handshake may have been flooded).
    let third = accept_within(&l);
    assert!(join.try_wait().unwrap().is_none(), "join --runs 0 exited");
    // Stopped in the middle of that one's handshake: at once, and a stop.
    let (o, took) = terminate(join);
    drop(third);
    deltaloop_supervisor::ops::loopback::remove_root(&root, false);
    let err = text(&o.stderr);
    assert!(took < Duration::from_secs(3), "{took:?}: {err}");
    assert_eq!(o.status.code(), Some(5), "{err}");
    assert!(
        err.contains("closed the connection during the handshake; trying again"),
        "{err}"
    );
}

/// The shared-memory files of iceoryx2 root `root`.
fn shm_of(root: &Path) -> Vec<String> {
    let (_, prefix) = deltaloop_transport::ipc::root_of(root.to_str().unwrap()).unwrap();
    std::fs::read_dir("/dev/shm")
        .unwrap()
        .flatten()
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| n.starts_with(&prefix))
        .collect()
}

/// Regression: a far bridge killed with -9 left its shared memory (17 entries, 11 MiB) and its
/// temp folder, and later `join`s never removed them; the next `join` on that host does.
#[test]
fn regression_what_a_far_bridge_killed_outright_left_is_removed_by_the_next_join() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let (tmp, cfg, key, ep) = s1_with_key();
    let out = tmp.path().join("remote");
    // Long enough (20 s of hold) to be killed in the middle of.
    let mut args = remote_lockstep(&cfg, &ep, &key, &out).to_vec();
    args.extend(["--hold-s", "20"]);
    let run = common::spawn(&args);
    let far_root = tmp.path().join("far-root");
    let join = join_with(&ep, &key, &far_root);
    // Once the far side holds the run's services, it dies outright.
    let t0 = std::time::Instant::now();
    while shm_of(&far_root).len() < 5 {
        assert!(
            t0.elapsed() < Duration::from_secs(60),
            "the far side never opened the run's services"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
    std::thread::sleep(Duration::from_secs(1));
    // SAFETY: our own child (`join` exec'd the far bridge), not yet reaped.
    unsafe { libc::kill(join.id() as i32, libc::SIGKILL) };
    let _ = common::finish_within(join, Duration::from_secs(10), "the killed join");
    let _ = common::finish_within(run, Duration::from_secs(60), "deltaloop run");
    let left = shm_of(&far_root);
    assert!(!left.is_empty(), "nothing was left to remove");
    // The next join on this host, even one that reaches nobody, removes it first.
    let next = Command::new(env!("CARGO_BIN_EXE_deltaloop"))
        .args([
            "join",
            &format!("127.0.0.1:{}", free_port()),
            "--wait-s",
            "1",
        ])
        .args(["--link-key", key.to_str().unwrap()])
        .env("DELTALOOP_IOX2_ROOT", &far_root)
        .output()
        .unwrap();
    let err = text(&next.stderr);
    // Every resource of the dead nodes; iceoryx2's own management file of the root stays (the
    // new join made it, as any process of that root does).
    let after: Vec<String> = shm_of(&far_root)
        .into_iter()
        .filter(|n| !n.ends_with(".global_mgmt"))
        .collect();
    deltaloop_supervisor::ops::loopback::remove_root(&far_root, false);
    assert!(
        err.contains("removed what earlier far bridges killed outright left"),
        "{err}"
    );
    assert!(after.is_empty(), "of {left:?}, left: {after:?}");
}

/// Regression: the far side's process (the controller or the plant `join` starts, and any
/// `--controller-cmd`/`--plant-cmd`, third-party code) inherited `DELTALOOP_LINK_KEY`, the
/// long-lived link key, from the far bridge. A controller command that writes its environment
/// to a file, then runs the built-in controller, completes the run and was given no secret.
#[test]
fn regression_the_far_process_is_not_given_the_link_key() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let (tmp, cfg, key, ep) = s1_with_key();
    let seen = tmp.path().join("far-env.txt");
    let script = tmp.path().join("env-controller.sh");
    std::fs::write(
        &script,
        format!(
            "#!/bin/sh\nenv > '{}'\nexec '{}' \"$@\"\n",
            seen.display(),
            env!("CARGO_BIN_EXE_deltaloop-controller")
        ),
    )
    .unwrap();
    use std::os::unix::fs::PermissionsExt;
    std::fs::set_permissions(&script, std::fs::Permissions::from_mode(0o700)).unwrap();
    let out = tmp.path().join("remote");
    let run = common::spawn(&remote_lockstep(&cfg, &ep, &key, &out));
    let far_root = tmp.path().join("far-root");
    let join = join_with_cmd(&ep, &key, &far_root, &script.display().to_string());
    let (o, j) = finish_pair(run, join, &far_root);
    assert!(o.status.success(), "{}", text(&o.stderr));
    assert!(j.status.success(), "join: {}", text(&j.stderr));
    let env = std::fs::read_to_string(&seen).expect("the far controller wrote its environment");
    let hex = deltaloop_bridge::seal::LinkKey::read(&key)
        .unwrap()
        .to_hex();
    assert!(
        env.contains("DELTALOOP_IOX2_ROOT="),
        "the environment it reports: {env}"
    );
    assert!(
        !env.contains(deltaloop_bridge::seal::KEY_ENV) && !env.contains(&hex),
        "the far controller was given the link key: {env}"
    );
}

/// Regression: a near side busy with a flood of connections without the key dropped an honest
/// `join` unheard, and `join` (any `--runs` but 0) gave up, blaming the key ("does it hold this
/// link key?"). The busy notice has `join --runs 1` say the near side is busy and connect again,
/// and the handshake that follows succeeds.
#[test]
fn regression_join_tries_a_busy_near_side_again_and_does_not_blame_the_key() {
    let tmp = tempfile::tempdir().unwrap();
    let key = tmp.path().join("link.key");
    let k = deltaloop_bridge::seal::LinkKey::write_new(&key).unwrap();
    let l = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let port = l.local_addr().unwrap().port();
    let root = tmp.path().join("far-root");
    let join = join_runs(port, &key, 1, &root);
    let first = accept_within(&l);
    deltaloop_bridge::seal::busy(&first);
    first.shutdown(std::net::Shutdown::Write).unwrap();
    let again = accept_within(&l);
    let joined = joins(again, &k);
    let (o, _) = terminate(join);
    drop(first);
    deltaloop_supervisor::ops::loopback::remove_root(&root, false);
    let err = text(&o.stderr);
    assert!(joined, "no JOIN came: {err}");
    assert!(
        err.contains("is busy authenticating other connections"),
        "{err}"
    );
    assert!(
        err.contains("trying again") && err.contains("joined the run"),
        "{err}"
    );
    assert!(!err.contains("link key?"), "{err}");
}

/// Whether the far side on `s` proves `key` and sends its JOIN (within 30 s), as a near side
/// would have it: the event after which `join` says it joined the run.
fn joins(mut s: std::net::TcpStream, key: &deltaloop_bridge::seal::LinkKey) -> bool {
    use deltaloop_bridge::{frame::Kind, link::Tcp, seal};
    let session = seal::Session::generate().unwrap();
    if seal::respond(&mut s, key, &session, Duration::from_secs(10)).is_err() {
        return false;
    }
    let mut tcp = Tcp::new(s, &session, seal::End::Near).unwrap();
    let t0 = std::time::Instant::now();
    while t0.elapsed() < Duration::from_secs(30) && !tcp.closed {
        let mut join = false;
        let heard = tcp.poll(|k, _| {
            join |= k == Kind::Join;
            Ok(())
        });
        if heard.is_err() {
            return false;
        }
        if join {
            return true;
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    false
}

/// Regression: a near side that closed the connection in the handshake (as a loaded one does
/// at its 2 s deadline) or did not answer in time ended `join --runs 1`, and a closed
/// connection was blamed on the key ("does it hold this link key?"). `join` tries again until
/// `--wait-s` runs out, says what happened without naming the key, and joins when it can.
#[test]
fn regression_join_tries_again_when_the_near_side_closes_or_times_out() {
    let tmp = tempfile::tempdir().unwrap();
    let key = tmp.path().join("link.key");
    let k = deltaloop_bridge::seal::LinkKey::write_new(&key).unwrap();
    let l = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let port = l.local_addr().unwrap().port();
    let root = tmp.path().join("far-root");
    let join = join_runs(port, &key, 1, &root);
    // Closed once its first message came; then silent until join's 2 s ran out.
    let mut first = accept_within(&l);
    let mut m = [0u8; 2];
    std::io::Read::read_exact(&mut first, &mut m).unwrap();
    drop(first);
    let silent = accept_within(&l);
    let joined = joins(accept_within(&l), &k);
    let (o, _) = terminate(join);
    drop(silent);
    deltaloop_supervisor::ops::loopback::remove_root(&root, false);
    let err = text(&o.stderr);
    assert!(joined, "no JOIN came: {err}");
    for said in [
        "closed the connection during the handshake; trying again",
        "did not complete the handshake within 2 s; trying again",
        "joined the run",
    ] {
        assert!(err.contains(said), "{said}: {err}");
    }
    assert!(!err.contains("link key?"), "{err}");
}

/// Regression: the near side counts a connection as having proved the key only by its first
/// sealed frame (a replayed first handshake message proves nothing), so a flood can drop an
/// honest one for room after answering its handshake, before reading its JOIN. `join` heard the
/// busy notice where it waited for the HELLO, said "sent no HELLO" and gave up; it connects
/// again, as for any busy near side.
#[test]
fn regression_join_dropped_for_room_after_the_handshake_tries_again() {
    use deltaloop_bridge::seal;
    let tmp = tempfile::tempdir().unwrap();
    let key = tmp.path().join("link.key");
    let k = seal::LinkKey::write_new(&key).unwrap();
    let l = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let port = l.local_addr().unwrap().port();
    let root = tmp.path().join("far-root");
    let join = join_runs(port, &key, 1, &root);
    let mut first = accept_within(&l);
    let session = seal::Session::generate().unwrap();
    seal::respond(&mut first, &k, &session, Duration::from_secs(10)).unwrap();
    seal::busy(&first);
    first.shutdown(std::net::Shutdown::Both).unwrap();
    let joined = joins(accept_within(&l), &k);
    let (o, _) = terminate(join);
    drop(first);
    deltaloop_supervisor::ops::loopback::remove_root(&root, false);
    let err = text(&o.stderr);
    assert!(joined, "no JOIN came: {err}");
    assert!(err.contains("trying again"), "{err}");
    assert!(
        !err.contains("sent no HELLO") && !err.contains("link key?"),
        "{err}"
    );
}
