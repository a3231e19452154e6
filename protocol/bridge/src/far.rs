//! The far side (`deltaloop-bridge far`, started by `deltaloop join`): connects to the near side,
//! learns the run from its HELLO (run id, mode, law, the resolved config), stands in for the
//! supervisor and the plant on this host's iceoryx2 (it creates the run's services, publishes
//! states and run control, sends the reference chunks) and starts the controller here, the
//! built-in one or any command, with the usual arguments. The controller cannot tell it is not on
//! the plant's host.

use crate::frame::{self, Hello, Kind, bytes_of};
use crate::link::{self, Tcp, Udp};
use crate::replies::Outbox;
use anyhow::{Context, Result, bail};
use deltaloop_config::{Law, LoopMode, RunConfig};
use deltaloop_transport::exit::{EXIT_FAULT, EXIT_SETUP, EXIT_STOPPED};
use deltaloop_transport::ipc::{self, IpcContext, Svc};
use deltaloop_transport::rt;
use deltaloop_transport::wire::{
    self, ControlKind, ControlMsg, RefSample, Sender, StateMsg, TorqueMsg,
};
use iceoryx2::port::listener::Listener;
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;
use std::io::{ErrorKind, Read};
use std::net::{SocketAddr, TcpStream, UdpSocket};
use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

/// `deltaloop-bridge far`.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// The near side: HOST:PORT given to `deltaloop run --controller-remote`.
    #[arg(long, value_parser = crate::parse_endpoint)]
    pub connect: SocketAddr,
    /// Only `controller` (the controller runs here, the plant and the supervisor there).
    #[arg(long, default_value = "controller", value_parser = ["controller"])]
    pub role: String,
    /// Run this controller command instead of the built-in `deltaloop-controller` (split at
    /// whitespace); the run's arguments are appended as for `--controller-cmd`.
    #[arg(long, value_name = "CMD")]
    pub controller_cmd: Option<String>,
    /// Runs to serve, one after the other (0: until interrupted).
    #[arg(long, default_value_t = 1)]
    pub runs: u32,
    /// How long to keep trying to reach the near side for each run, s (0: forever).
    #[arg(long, default_value_t = 120)]
    pub wait_s: u64,
    /// Poll this long for the controller's reply after publishing a state before blocking, µs
    /// (0: block at once; at most loop.torque_budget_us in realtime).
    #[arg(long, default_value_t = 0)]
    pub spin_us: u32,
}

/// Serves `a.runs` runs; the exit code is the last controller's (or why the bridge failed).
pub fn run(a: &Args, term: &AtomicBool) -> Result<(u8, Option<String>)> {
    let cmd: Vec<String> = match &a.controller_cmd {
        Some(c) => c.split_whitespace().map(str::to_string).collect(),
        None => vec![
            crate::exe_dir()?
                .join("deltaloop-controller")
                .display()
                .to_string(),
        ],
    };
    if cmd.is_empty() {
        bail!("--controller-cmd is empty: give a program and its arguments");
    }
    let mut last = (0, None);
    let mut served = 0;
    while a.runs == 0 || served < a.runs {
        let Some(stream) = connect(a, term)? else {
            return Ok((
                EXIT_STOPPED,
                Some("interrupted while waiting for the near side".into()),
            ));
        };
        last = serve(a, stream, &cmd, term)?;
        served += 1;
        if term.load(Ordering::Relaxed) {
            break;
        }
        if a.runs != 1 {
            // The near side of the next run listens once its supervisor has started it.
            std::thread::sleep(Duration::from_millis(200));
        }
    }
    Ok(last)
}

fn connect(a: &Args, term: &AtomicBool) -> Result<Option<TcpStream>> {
    let end = rt::now_ns().saturating_add(a.wait_s.saturating_mul(1_000_000_000));
    loop {
        match TcpStream::connect_timeout(&a.connect, Duration::from_secs(1)) {
            Ok(s) => return Ok(Some(s)),
            Err(e) if a.wait_s > 0 && rt::now_ns() > end => {
                bail!(
                    "cannot reach the near side at {} within {} s: {e}",
                    a.connect,
                    a.wait_s
                )
            }
            Err(_) => {}
        }
        if term.load(Ordering::Relaxed) {
            return Ok(None);
        }
        std::thread::sleep(Duration::from_millis(100));
    }
}

/// The supervisor's and the plant's ports on this host.
struct Ports {
    state: Publisher<Svc, StateMsg, ()>,
    torque: Subscriber<Svc, TorqueMsg, ()>,
    state_ready: Notifier<Svc>,
    torque_ready: Listener<Svc>,
    control: Publisher<Svc, ControlMsg, ()>,
    control_in: Subscriber<Svc, ControlMsg, ()>,
    reference: Publisher<Svc, [RefSample], ()>,
    _node: Node<Svc>,
}

impl Ports {
    fn open(run_id: &str) -> Result<Self> {
        let node = ipc::node("supervisor", run_id)?;
        let (state, torque, state_ready, torque_ready) =
            ipc::plant_loop(&node, run_id, ipc::RELAY_BUFFER)?;
        Ok(Self {
            state,
            torque,
            state_ready,
            torque_ready,
            control: ipc::control(&node, run_id, Sender::Supervisor)?
                .publisher_builder()
                .create()
                .ipc("control publisher")?,
            control_in: ipc::control(&node, run_id, Sender::Controller)?
                .subscriber_builder()
                .create()
                .ipc("control-controller subscriber")?,
            reference: ipc::reference_publisher(&node, run_id)?,
            _node: node,
        })
    }
}

/// One run: HELLO, ports, the controller, the loop, the end.
fn serve(
    a: &Args,
    stream: TcpStream,
    cmd: &[String],
    term: &AtomicBool,
) -> Result<(u8, Option<String>)> {
    let mut tcp = Tcp::new(stream)?;
    let mut hello = None;
    let end = rt::now_ns() + ipc::HANDSHAKE_TIMEOUT_NS;
    while hello.is_none() {
        let mut err = None;
        tcp.poll(|k, p| {
            match (k, Hello::decode(p)) {
                (Kind::Hello, Ok(h)) => hello = Some(h),
                (Kind::Hello, Err(e)) => err = Some(e),
                _ => {}
            }
            Ok(())
        })?;
        if let Some(e) = err {
            bail!("{e}");
        }
        if tcp.closed || rt::now_ns() > end {
            bail!("the near side at {} sent no HELLO", a.connect);
        }
        std::thread::sleep(Duration::from_millis(1));
    }
    let hello = hello.unwrap_or_else(|| unreachable!());
    let key = frame::run_key(&hello.run_id);
    let fail = |tcp: &mut Tcp, why: String| -> Result<(u8, Option<String>)> {
        let line = format!("far side: {why}");
        tcp.send(
            Kind::Exit,
            key,
            &[&u32::from(EXIT_SETUP).to_ne_bytes(), line.as_bytes()],
        )?;
        let t = rt::now_ns() + 1_000_000_000;
        while tcp.pending() > 0 && rt::now_ns() < t {
            tcp.flush()?;
            std::thread::sleep(Duration::from_millis(1));
        }
        Ok((EXIT_SETUP, Some(line)))
    };
    let mode = match LoopMode::parse_process(&hello.mode) {
        Ok(m) => m,
        Err(e) => return fail(&mut tcp, format!("mode {}: {e}", hello.mode)),
    };
    if let Err(e) = Law::parse(&hello.law) {
        return fail(&mut tcp, format!("law {}: {e}", hello.law));
    }
    let dir = std::env::temp_dir().join(format!(
        "deltaloop-join-{}-{}",
        std::process::id(),
        hello.run_id
    ));
    let _tmp = TempDir(dir.clone());
    std::fs::create_dir_all(&dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let config = dir.join("config.toml");
    std::fs::write(&config, &hello.config)?;
    if let Err(e) = RunConfig::from_file(&config) {
        return fail(&mut tcp, format!("the run's config: {e:#}"));
    }
    tcp.set_key(key);
    let ports = match Ports::open(&hello.run_id) {
        Ok(p) => p,
        Err(e) => return fail(&mut tcp, format!("{e:#}")),
    };
    let local = tcp.stream.local_addr()?;
    let udp = UdpSocket::bind(SocketAddr::new(local.ip(), 0))?;
    udp.connect(a.connect)?;
    let port = u64::from(udp.local_addr()?.port());
    let mut far_emu = hello.emulation;
    far_emu.seed = far_emu.seed.wrapping_add(1);
    let mut udp = Udp::new(udp, key, far_emu)?;
    let spin_ns = match crate::spin_ns(&config, mode, a.spin_us) {
        Ok(s) => s,
        Err(e) => return fail(&mut tcp, format!("{e:#}")),
    };
    let child = match spawn(cmd, &hello, mode, &config) {
        Ok(c) => c,
        Err(e) => return fail(&mut tcp, format!("{e:#}")),
    };
    tcp.send(Kind::Ack, key, &[&port.to_ne_bytes()])?;
    udp.send(Kind::Punch, &[], rt::now_ns())?;
    let mut f = Far {
        ports,
        udp,
        tcp,
        key,
        child,
        stderr_buf: Vec::with_capacity(4096),
        last_line: String::new(),
        started: false,
        stash: None,
        arrived: (u64::MAX, 0),
        controller_poll_until: 0,
        stop_sent: false,
        near_gone_ns: None,
        spin_ns,
        poll_until: 0,
        arrivals: [(u64::MAX, 0); ARRIVALS],
        replies: Outbox::default(),
    };
    let code = f.forward(term)?;
    f.report(code)?;
    std::thread::sleep(ipc::LINGER);
    let line = (!f.last_line.is_empty()).then(|| f.last_line.clone());
    drop(f);
    let id = hello.run_id.clone();
    ipc::remove_dead_nodes_where(|n| n.ends_with(&id));
    Ok((code, line))
}

/// Removes the run's temporary folder (its config) when the run is over.
struct TempDir(PathBuf);

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

fn spawn(cmd: &[String], h: &Hello, mode: LoopMode, config: &std::path::Path) -> Result<Child> {
    let mut c = Command::new(&cmd[0]);
    c.args(&cmd[1..])
        .args(["--run-id", &h.run_id, "--config"])
        .arg(config)
        .args(["--mode", mode.name(), "--law", &h.law])
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::piped());
    // SAFETY: signal() and prctl() are async-signal-safe; nothing else runs between fork and exec.
    unsafe {
        use std::os::unix::process::CommandExt;
        c.pre_exec(|| {
            libc::signal(libc::SIGINT, libc::SIG_IGN);
            libc::signal(libc::SIGHUP, libc::SIG_IGN);
            libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGTERM);
            Ok(())
        });
    }
    let child = c
        .spawn()
        .with_context(|| format!("cannot start the controller `{}`", cmd.join(" ")))?;
    if let Some(e) = &child.stderr {
        use std::os::fd::AsRawFd;
        // SAFETY: setting O_NONBLOCK on a pipe descriptor we own.
        unsafe {
            let fl = libc::fcntl(e.as_raw_fd(), libc::F_GETFL);
            libc::fcntl(e.as_raw_fd(), libc::F_SETFL, fl | libc::O_NONBLOCK);
        }
    }
    Ok(child)
}

struct Far {
    ports: Ports,
    udp: Udp,
    tcp: Tcp,
    key: u64,
    child: Child,
    stderr_buf: Vec<u8>,
    last_line: String,
    /// START has been published here.
    started: bool,
    /// A state that came before START (the datagram overtook the TCP frame).
    stash: Option<StateMsg>,
    /// The last state published here: its tick and when it arrived (this host's clock, ns).
    arrived: (u64, u64),
    /// When each of the last [`ARRIVALS`] states arrived: (tick, ns), at slot tick % ARRIVALS, so
    /// a reply to an older state still gets its residence here.
    arrivals: [(u64, u64); ARRIVALS],
    /// The controller's last `t_poll_until_ns` (this host's clock).
    controller_poll_until: u64,
    stop_sent: bool,
    /// When the near side closed the control connection.
    near_gone_ns: Option<u64>,
    /// How long to poll for the reply after publishing a state, ns.
    spin_ns: u64,
    /// Poll (do not block) until then: a reply is due.
    poll_until: u64,
    /// The last replies sent (with their residences), each datagram carrying the two before
    /// it too; sent again for a state the near side sends again (lockstep, after a loss).
    replies: Outbox,
}

/// States whose arrival time the far side keeps.
const ARRIVALS: usize = 64;

impl Drop for Far {
    fn drop(&mut self) {
        if self.child.try_wait().ok().flatten().is_none() {
            // SAFETY: signalling our own child, not yet reaped.
            unsafe { libc::kill(self.child.id() as i32, libc::SIGTERM) };
            for _ in 0..200 {
                if self.child.try_wait().ok().flatten().is_some() {
                    return;
                }
                std::thread::sleep(Duration::from_millis(5));
            }
            let _ = self.child.kill();
            let _ = self.child.wait();
        }
    }
}

impl Far {
    /// Carries the run until the controller exits; its exit code.
    fn forward(&mut self, term: &AtomicBool) -> Result<u8> {
        let mut next_check = 0u64;
        loop {
            let now = rt::now_ns();
            let timeout = if now < self.poll_until {
                0
            } else {
                link::timeout_ns(&self.udp, now)
            };
            let err_fd = self
                .child
                .stderr
                .as_ref()
                .map_or(-1, std::os::fd::AsRawFd::as_raw_fd);
            let mut fds = [
                link::readable(&self.udp.sock),
                link::readable(&self.tcp.stream),
                link::event(&self.ports.torque_ready),
                libc::pollfd {
                    fd: err_fd,
                    events: libc::POLLIN,
                    revents: 0,
                },
            ];
            if self.tcp.pending() > 0 {
                fds[1].events |= libc::POLLOUT;
            }
            link::wait(&mut fds, timeout)?;
            let [udp_in, tcp_in, torque_in, err_in] = fds.map(|f| f.revents != 0);
            if torque_in || now < self.poll_until {
                self.torques()?;
            }
            if udp_in {
                self.states()?;
            }
            self.udp.flush(rt::now_ns())?;
            self.control_plane(tcp_in)?;
            let now = rt::now_ns();
            if err_in {
                self.stderr()?;
            }
            if term.load(Ordering::Relaxed) || self.tcp.closed {
                if !self.stop_sent {
                    self.stop_sent = true;
                    let stop = ControlMsg::new(ControlKind::Stop, Sender::Supervisor);
                    self.ports.control.send_copy(stop).ipc("publish STOP")?;
                }
                if self.tcp.closed {
                    let gone = *self.near_gone_ns.get_or_insert(now);
                    if now > gone + 3_000_000_000 {
                        // SAFETY: signalling our own child, not yet reaped.
                        unsafe { libc::kill(self.child.id() as i32, libc::SIGTERM) };
                    }
                }
            }
            if err_in || now > next_check {
                next_check = now + 50_000_000;
                if let Some(st) = self.child.try_wait()? {
                    self.stderr()?;
                    use std::os::unix::process::ExitStatusExt;
                    let code = match (st.code(), st.signal()) {
                        (Some(c), _) => u8::try_from(c).unwrap_or(EXIT_FAULT),
                        (None, Some(sig)) => {
                            self.last_line = format!("the controller was killed by signal {sig}");
                            EXIT_FAULT
                        }
                        _ => EXIT_FAULT,
                    };
                    return Ok(code);
                }
            }
        }
    }

    /// The controller's replies, out as datagrams with the residence here.
    fn torques(&mut self) -> Result<()> {
        self.ports
            .torque_ready
            .try_wait(|_| {})
            .ipc("drain torque-ready")?;
        while let Some(s) = self.ports.torque.receive().ipc("receive torque")? {
            let t: &TorqueMsg = s.payload();
            self.controller_poll_until = t.t_poll_until_ns;
            self.poll_until = 0;
            let now = rt::now_ns();
            let (tick, at) = self.arrivals[(t.tick % ARRIVALS as u64) as usize];
            let residence = if tick == t.tick {
                now.saturating_sub(at)
            } else {
                t.t_publish_ns.saturating_sub(t.t_state_rx_ns)
            };
            let payload = self.replies.push(t, residence);
            self.udp.send(Kind::Torque, &[payload], now)?;
        }
        Ok(())
    }

    /// The plant's states from the link, published here.
    fn states(&mut self) -> Result<()> {
        while let Some((kind, p)) = self.udp.recv()? {
            if kind != Kind::State {
                continue;
            }
            let Some(s) = frame::read::<StateMsg>(p) else {
                continue;
            };
            if self.replies.newest_tick() == Some(s.tick) {
                // Sent again: its reply was lost on the way back.
                let now = rt::now_ns();
                self.udp
                    .send(Kind::Torque, &[self.replies.payload()], now)?;
            } else if self.started && self.arrived.0 == s.tick {
                // Sent again while the controller is still on it: it answers once.
            } else if self.started {
                self.publish_state(s)?;
            } else {
                self.stash = Some(s);
            }
        }
        Ok(())
    }

    fn publish_state(&mut self, mut s: StateMsg) -> Result<()> {
        // This side polls for the reply until poll_until, then blocks on the torque event
        // (docs/protocol.md §6.1, on this host's clock).
        let now = rt::now_ns();
        self.poll_until = now + self.spin_ns;
        s.t_poll_until_ns = self.poll_until;
        self.arrived = (s.tick, now);
        self.arrivals[(s.tick % ARRIVALS as u64) as usize] = (s.tick, now);
        self.ports.state.send_copy(s).ipc("publish state")?;
        if ipc::published_needs_notify(self.controller_poll_until) {
            self.ports.state_ready.notify().ipc("notify state")?;
        }
        Ok(())
    }

    fn control_plane(&mut self, tcp_in: bool) -> Result<()> {
        while let Some(s) = self.ports.control_in.receive().ipc("receive control")? {
            let c = *s.payload();
            if matches!(c.kind(), Some(ControlKind::Ready | ControlKind::Armed)) {
                self.tcp.send(Kind::Control, self.key, &[bytes_of(&c)])?;
            }
        }
        if self.tcp.pending() > 0 {
            self.tcp.flush()?;
        }
        if !tcp_in {
            return Ok(());
        }
        let (ports, started) = (&self.ports, &mut self.started);
        let mut finals = None;
        self.tcp.poll(|kind, p| {
            match kind {
                Kind::Control => {
                    let Some(mut c) = frame::read::<ControlMsg>(p) else {
                        return Ok(());
                    };
                    match c.kind() {
                        Some(ControlKind::Start) => {
                            c.t0_ns = crate::near::absolute_t0(c.t0_ns);
                            ports.control.send_copy(c).ipc("publish START")?;
                            *started = true;
                        }
                        Some(ControlKind::Stop) => {
                            ports.control.send_copy(c).ipc("publish STOP")?;
                        }
                        _ => {}
                    }
                }
                Kind::Reference => {
                    let rows = p.len() / size_of::<RefSample>();
                    let chunk = ports
                        .reference
                        .loan_slice_uninit(rows)
                        .ipc("loan a reference chunk")?;
                    let chunk = chunk.write_from_fn(|i| {
                        frame::read::<RefSample>(
                            &p[i * size_of::<RefSample>()..(i + 1) * size_of::<RefSample>()],
                        )
                        .unwrap_or_default()
                    });
                    chunk.send().ipc("send a reference chunk")?;
                }
                Kind::Final => finals = frame::read::<StateMsg>(p),
                _ => {}
            }
            Ok(())
        })?;
        if self.started
            && let Some(s) = self.stash.take()
        {
            self.publish_state(s)?;
        }
        if let Some(s) = finals {
            self.publish_state(s)?;
        }
        Ok(())
    }

    /// The controller's stderr: shown here and sent to the near side line by line.
    fn stderr(&mut self) -> Result<()> {
        let Some(err) = self.child.stderr.as_mut() else {
            return Ok(());
        };
        let mut buf = [0u8; 4096];
        loop {
            match err.read(&mut buf) {
                Ok(0) => break,
                Ok(n) => self.stderr_buf.extend_from_slice(&buf[..n]),
                Err(e) if e.kind() == ErrorKind::WouldBlock => break,
                Err(e) if e.kind() == ErrorKind::Interrupted => {}
                Err(_) => break,
            }
        }
        while let Some(i) = self.stderr_buf.iter().position(|&b| b == b'\n') {
            let line: Vec<u8> = self.stderr_buf.drain(..=i).collect();
            let line = wire::escape_peer_text(&String::from_utf8_lossy(&line[..i]));
            eprintln!("{line}");
            self.tcp.send(Kind::Log, self.key, &[line.as_bytes()])?;
            self.last_line = line;
        }
        Ok(())
    }

    /// Tells the near side how the controller ended, and waits (a little) for it to go out.
    fn report(&mut self, code: u8) -> Result<()> {
        let line = self.last_line.clone();
        self.tcp.send(
            Kind::Exit,
            self.key,
            &[&u32::from(code).to_ne_bytes(), line.as_bytes()],
        )?;
        let t = rt::now_ns() + 500_000_000;
        while self.tcp.pending() > 0 && !self.tcp.closed && rt::now_ns() < t {
            self.tcp.flush()?;
            std::thread::sleep(Duration::from_millis(1));
        }
        Ok(())
    }
}
