//! The listener: where the near side waits for the far side, admits it ([`super::admit`]),
//! says the HELLO and connects the link's UDP socket to the port the far side answers with.

use super::admit::accept_far;
use super::*;

/// Waits for the far side's ACK with its UDP port (up to the ACK only: what it says after it,
/// READY, is the loop's to forward). None: STOP or SIGTERM came first.
fn await_ack(
    tcp: &mut Tcp,
    peer: SocketAddr,
    (control, term): (&ControlPorts, &AtomicBool),
    end: u64,
) -> Result<Option<u64>> {
    let (mut far_udp, mut far_end) = (None, None);
    while far_udp.is_none() {
        tcp.poll_until(|k, p| {
            match k {
                Kind::Ack => far_udp = bytes::read::<u64>(p),
                Kind::Exit => far_end = Some(FarEnd::of(p)),
                _ => {}
            }
            Ok(far_udp.is_some())
        })?;
        if let Some(e) = far_end {
            // The far side refused the run (wrong role, a bad config, …): its line says why.
            bail!("{}", e.line);
        }
        if tcp.closed {
            bail!("the far side {peer} closed the link during the handshake");
        }
        if rt::now_ns() > end {
            bail!("the far side {peer} did not answer the HELLO");
        }
        if stopped(control, term)? {
            return Ok(None);
        }
        std::thread::sleep(Duration::from_millis(1));
    }
    Ok(far_udp)
}

/// Waits for the far side: every connection must prove the link key before anything of the run
/// is said, a stranger's is dropped (and counted) and the wait goes on; at most
/// [`MAX_PENDING`](super::admit::MAX_PENDING) are authenticated at once, each within
/// [`PER_CONNECTION`](super::admit::PER_CONNECTION) of its accept. Then sends the HELLO and
/// connects the UDP socket to the port the far side answers with; the link report is written at
/// once, so a far side that joined and then fell silent is named by the supervisor.
/// None: stopped (STOP or SIGTERM) before it joined.
pub(super) fn connect(
    at: &Listen,
    hello: &Hello,
    control: &ControlPorts,
    term: &AtomicBool,
    report_path: &std::path::Path,
) -> Result<Option<Peer>> {
    let key = LinkKey::from_env().map_err(anyhow::Error::msg)?;
    let session = Session::generate().map_err(anyhow::Error::msg)?;
    let listener = TcpListener::bind(at.addr)
        .with_context(|| format!("cannot listen on --listen {} (TCP)", at.addr))?;
    let udp = UdpSocket::bind(at.addr)
        .with_context(|| format!("cannot bind --listen {} (UDP)", at.addr))?;
    listener.set_nonblocking(true)?;
    // The far side connects: wait for it as long as a handshake step may take.
    let end = rt::now_ns() + ipc::HANDSHAKE_TIMEOUT_NS;
    let mut stop = || stopped(control, term);
    let Some(((mut tcp, peer, role), refused)) =
        accept_far(at, &listener, (&key, &session), &mut stop, end)?
    else {
        return Ok(None);
    };
    drop(listener);
    if let Some(r) = role.filter(|r| *r != at.role) {
        bail!(
            "the far side {peer} joined with --role {r}, and this run puts the {} there (run `deltaloop join {} --role {}` on the other host)",
            at.role,
            at.addr,
            at.role
        );
    }
    tcp.send(Kind::Hello, &[&hello.encode()])?;
    let Some(far_port) = await_ack(&mut tcp, peer, (control, term), end)? else {
        return Ok(None);
    };
    let Ok(far_port) = u16::try_from(far_port) else {
        bail!("the far side sent UDP port {far_port} (allowed 1..=65535)");
    };
    udp.connect(SocketAddr::new(peer.ip(), far_port))
        .context("connect the link's UDP socket")?;
    eprintln!(
        "deltaloop-bridge: the far side {peer} joined (link key {})",
        key.fingerprint()
    );
    let report = LinkReport {
        peer: peer.to_string(),
        key_fingerprint: key.fingerprint(),
        refused_connections: refused,
        ..LinkReport::default()
    };
    if let Err(e) = report.write(report_path) {
        eprintln!("deltaloop-bridge: warning: {e}");
    }
    Ok(Some(Peer {
        udp: Udp::sealed(udp, &session, End::Near, hello.emulation)?,
        tcp,
        far_end: None,
        stop_sent_ns: None,
        log: FarLog::default(),
        report,
        session,
        handoff: None,
        relay: false,
        direct: false,
        role: at.role,
        loop_cpu: None,
    }))
}

/// Whether the supervisor said STOP (or SIGTERM came), before START.
fn stopped(control: &ControlPorts, term: &AtomicBool) -> Result<bool> {
    let mut stop = term.load(Ordering::Relaxed);
    while let Some(s) = control.1.receive().ipc("receive control")? {
        stop |= s.kind() == Some(ControlKind::Stop);
    }
    Ok(stop)
}
