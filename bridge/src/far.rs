//! The far side (`deltaloop-bridge far`, started by `deltaloop join`): connects to the near side,
//! learns the run from its HELLO (run id, role, mode, law, the resolved config), and starts the
//! process the run puts on this host, the built-in one or any command, with the usual arguments:
//!
//! - `--role controller`: it stands in for the supervisor and the plant on this host's iceoryx2
//!   (it creates the run's services, publishes states and run control, sends the reference
//!   chunks) and starts the controller;
//! - `--role plant`: it stands in for the supervisor (START, STOP) and the controller (the
//!   replies, READY and ARMED) and starts the plant; the plant's telemetry, control messages and
//!   final state go to the near side over TCP.
//!
//! The process cannot tell it is not on the supervisor's host.

use crate::bytes::{self, bytes_of};
use crate::cli::{FarArgs as Args, Placement};
use crate::frame::Kind;
use crate::hello::Hello;
use crate::link::{self, Tcp, Udp};
use crate::seal::{self, End, LinkKey, Session};
use crate::sides::{ControllerHost, PlantHost};
use anyhow::{Context, Result, bail};
use deltaloop_config::RemoteSide;
use deltaloop_config::{Law, LoopMode, RunConfig};
use deltaloop_transport::exit::{EXIT_FAULT, EXIT_SETUP, EXIT_STOPPED};
use deltaloop_transport::ipc::{self, IpcContext, Svc};
use deltaloop_transport::rt;
use deltaloop_transport::wire::{self, ControlKind, ControlMsg, RefSample, Sender, StateMsg};
use std::io::{ErrorKind, Read};
use std::net::{SocketAddr, TcpStream, UdpSocket};
use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

mod relay;

use relay::*;

/// The run's config with the placement of the process that runs here (`role`) taken from this
/// host (`join --cpu/--priority`, else the mode's default layout), whatever the near side's
/// config asked (regression: a fake near side set the far controller's SCHED_FIFO priority and
/// CPU). A line saying what was replaced, if anything was.
fn this_hosts_placement(
    mut cfg: RunConfig,
    role: RemoteSide,
    p: Placement,
) -> (RunConfig, Option<String>) {
    use deltaloop_config::Layout;
    let mut replaced = Vec::new();
    for (name, layout, default) in [
        (
            "realtime",
            &mut cfg.loop_.realtime,
            Layout::realtime_default(),
        ),
        (
            "lockstep",
            &mut cfg.loop_.lockstep,
            Layout::lockstep_default(),
        ),
    ] {
        let (cpu, prio, dcpu, dprio) = match role {
            RemoteSide::Controller => (
                &mut layout.controller_cpu,
                &mut layout.controller_priority,
                default.controller_cpu,
                default.controller_priority,
            ),
            RemoteSide::Plant => (
                &mut layout.plant_cpu,
                &mut layout.plant_priority,
                default.plant_cpu,
                default.plant_priority,
            ),
        };
        let (want_cpu, want_prio) = (p.cpu.or(dcpu), p.priority.or(dprio));
        if *cpu != want_cpu || *prio != want_prio {
            replaced.push(format!(
                "{name} {role} CPU {} priority {} asked by the near side",
                show(*cpu),
                show(*prio)
            ));
        }
        (*cpu, *prio) = (want_cpu, want_prio);
    }
    let line = (!replaced.is_empty()).then(|| {
        format!(
            "the {role} runs where this host says (join --cpu/--priority, or the default layout), not where the near side asked ({})",
            replaced.join("; ")
        )
    });
    (cfg, line)
}

fn show(v: Option<i32>) -> String {
    v.map_or("default".into(), |v| v.to_string())
}

/// The command to start here for `role` (`cmd`: the user's, or None for the built-in one); one
/// line naming the flag otherwise.
pub fn command(
    role: RemoteSide,
    controller_cmd: Option<&str>,
    plant_cmd: Option<&str>,
) -> Result<Vec<String>> {
    let users = deltaloop_link_setup::far_command(role, controller_cmd, plant_cmd)
        .map_err(anyhow::Error::msg)?;
    Ok(match users {
        Some(cmd) => cmd,
        None => {
            let program = deltaloop_link_setup::far_program(role);
            vec![crate::exe_dir()?.join(program).display().to_string()]
        }
    })
}

/// Serves `a.runs` runs; the exit code is the last far process's (or why the bridge failed).
pub fn run(a: &Args, term: &AtomicBool) -> Result<(u8, Option<String>)> {
    let cmd = command(a.role, a.controller_cmd.as_deref(), a.plant_cmd.as_deref())?;
    remove_leftovers();
    let mut last = (0, None);
    let mut served = 0;
    while a.runs == 0 || served < a.runs {
        let Some(stream) = connect(a, term)? else {
            return Ok((
                EXIT_STOPPED,
                Some("interrupted while waiting for the near side".into()),
            ));
        };
        last = match serve(a, stream, &cmd, term) {
            Ok(end) => end,
            // Serving until interrupted: a connection that closed at once, a join that raced
            // this one, a near side that went away: say so and wait for the next run
            // (regression: `join --runs 0` exited).
            // Stopped mid-way (a SIGTERM cuts the handshake short): a stop, not a failure.
            Err(_) if term.load(Ordering::Relaxed) => {
                return Ok((
                    EXIT_STOPPED,
                    Some("interrupted while joining the near side".into()),
                ));
            }
            Err(e) if a.runs == 0 => {
                eprintln!("deltaloop-bridge: warning: {e:#}; waiting for the next run");
                std::thread::sleep(Duration::from_secs(1));
                continue;
            }
            Err(e) => return Err(e),
        };
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

/// `--role controller`: the supervisor's and the plant's ports on this host.
struct Ports {
    state: ipc::StateOut,
    torque: ipc::TorqueIn,
    state_ready: ipc::Ping,
    torque_ready: ipc::Wake,
    control: ipc::ControlOut,
    control_in: ipc::ControlIn,
    reference: ipc::RefOut,
    _node: ipc::RunNode,
}

/// The supervisor's `control` publisher and a subscriber on the service of `from`.
fn run_control(node: &ipc::Node<Svc>, run_id: &str, from: Sender) -> Result<ipc::ControlPorts> {
    Ok((
        ipc::control(node, run_id, Sender::Supervisor)?.publisher("control publisher")?,
        ipc::control(node, run_id, from)?
            .subscriber(None, &format!("{} subscriber", ipc::control_service(from)))?,
    ))
}

impl Ports {
    fn open(run_id: &str) -> Result<Self> {
        let node = ipc::node("supervisor", run_id)?;
        let (state, torque, state_ready, torque_ready) =
            ipc::plant_loop(&node, run_id, ipc::RELAY_BUFFER)?;
        let (control, control_in) = run_control(&node, run_id, Sender::Controller)?;
        Ok(Self {
            state,
            torque,
            state_ready,
            torque_ready,
            control,
            control_in,
            reference: ipc::reference_publisher(&node, run_id)?,
            _node: node,
        })
    }
}

/// `--role plant`: the supervisor's and the controller's ports on this host.
struct PlantSidePorts {
    state: ipc::StateIn,
    torque: ipc::TorqueOut,
    state_ready: ipc::Wake,
    torque_ready: ipc::Ping,
    control: ipc::ControlOut,
    /// The plant's control messages.
    control_in: ipc::ControlIn,
    /// READY and ARMED as the controller there says them.
    as_controller: ipc::ControlOut,
    telemetry: ipc::TelemetryIn,
    _node: ipc::RunNode,
}

impl PlantSidePorts {
    fn open(run_id: &str) -> Result<Self> {
        let node = ipc::node("supervisor", run_id)?;
        let (state, torque, state_ready, torque_ready) =
            ipc::controller_loop(&node, run_id, ipc::RELAY_BUFFER)?;
        let (control, control_in) = run_control(&node, run_id, Sender::Plant)?;
        Ok(Self {
            state,
            torque,
            state_ready,
            torque_ready,
            control,
            control_in,
            as_controller: ipc::control(&node, run_id, Sender::Controller)?
                .publisher("control-controller publisher")?,
            telemetry: ipc::telemetry(&node, run_id)?
                .subscriber(Some(ipc::OBSERVER_BUFFER), "telemetry subscriber")?,
            _node: node,
        })
    }
}

/// The ports of the role this side serves.
enum Either {
    Controller(Ports),
    Plant(PlantSidePorts),
}

/// How long a far side waits before it connects again to a near side that said it was busy,
/// closed the connection or did not answer in time.
const RETRY: Duration = Duration::from_millis(200);

/// Whether a failed handshake is worth another connection: the near side was busy, closed the
/// connection or did not answer in time, which a flood of connections or a loaded host causes
/// as well as a wrong key would (the near side's log says which). An answer that does not
/// authenticate is the key's fault, and final.
fn retried(e: &seal::HandshakeError) -> bool {
    use seal::HandshakeError::*;
    matches!(e, Busy | Closed | Timeout)
}

/// One handshake on `stream` ([`seal::initiate`], within [`seal::HANDSHAKE_BUDGET`] all told,
/// however the near side paces its answer). A SIGTERM during it shuts the socket, so the
/// blocking read ends at once (regression: a join waiting for a silent near side ignored SIGTERM
/// for seconds).
fn handshake(
    stream: &mut TcpStream,
    key: &LinkKey,
    term: &AtomicBool,
) -> Result<std::result::Result<Session, seal::HandshakeError>> {
    let done = AtomicBool::new(false);
    let watch = stream.try_clone()?;
    Ok(std::thread::scope(|sc| {
        sc.spawn(|| {
            while !done.load(Ordering::Relaxed) {
                if term.load(Ordering::Relaxed) {
                    let _ = watch.shutdown(std::net::Shutdown::Both);
                    return;
                }
                std::thread::sleep(Duration::from_millis(10));
            }
        });
        let r = seal::initiate(stream, key, seal::HANDSHAKE_BUDGET);
        done.store(true, Ordering::Relaxed);
        r
    }))
}

/// Proves the link key to the near side ([`seal::initiate`]: a near side without it cannot
/// answer), says which role this side joined for (the first sealed frame) and waits for the
/// HELLO (None: SIGTERM came first). A handshake that failed for want of the near side's
/// attention ([`retried`]), or a connection the near side dropped for room before it read the
/// JOIN (it counts a connection as proven only by that frame), is tried again until `--wait-s`
/// runs out, whatever `--runs` says. One line naming the near side otherwise.
fn join(
    a: &Args,
    mut stream: TcpStream,
    term: &AtomicBool,
) -> Result<Option<(Tcp, Session, Hello)>> {
    let key = LinkKey::from_env().map_err(anyhow::Error::msg)?;
    let end = rt::now_ns().saturating_add(a.wait_s.saturating_mul(1_000_000_000));
    // The last failure said, so each kind is said once, not at every try.
    let mut said = None;
    loop {
        let e = match handshake(&mut stream, &key, term)? {
            Ok(session) => {
                let mut tcp = Tcp::new(stream, &session, End::Far)?;
                tcp.send(Kind::Join, &[&crate::side_to_wire(a.role).to_ne_bytes()])?;
                eprintln!(
                    "deltaloop-bridge: joined the run at {} (link key {})",
                    a.connect,
                    key.fingerprint()
                );
                match await_hello(a, &mut tcp, term)? {
                    Heard::Hello(h) => return Ok(Some((tcp, session, h))),
                    Heard::Stopped => return Ok(None),
                    Heard::Dropped => seal::HandshakeError::Busy,
                }
            }
            Err(e) => e,
        };
        if !retried(&e) || term.load(Ordering::Relaxed) {
            bail!("the near side at {} {e}", a.connect);
        }
        if a.wait_s != 0 && rt::now_ns() >= end {
            bail!(
                "the near side at {} {e}, every try until --wait-s {} ran out (this side's link key: {}; the near side's log says why it turned this side away)",
                a.connect,
                a.wait_s,
                key.fingerprint()
            );
        }
        if said.as_ref() != Some(&e) {
            let until = match a.wait_s {
                0 => String::new(),
                s => format!(" for up to {s} s"),
            };
            eprintln!(
                "deltaloop-bridge: the near side at {} {e}; trying again{until} (this side's link key: {})",
                a.connect,
                key.fingerprint()
            );
            said = Some(e);
        }
        std::thread::sleep(RETRY);
        let Some(s) = connect(a, term)? else {
            bail!("interrupted while joining the near side at {}", a.connect);
        };
        stream = s;
    }
}

/// What came after the JOIN.
enum Heard {
    Hello(Hello),
    /// SIGTERM.
    Stopped,
    /// The near side closed the connection before any sealed frame: it dropped this one for
    /// room before it read the JOIN (its busy notice, or a bare close), as it may drop any
    /// connection that has not yet sent its first sealed frame.
    Dropped,
}

/// Waits for the near side's HELLO.
fn await_hello(a: &Args, tcp: &mut Tcp, term: &AtomicBool) -> Result<Heard> {
    let end = rt::now_ns() + ipc::HANDSHAKE_TIMEOUT_NS;
    let mut heard_any = false;
    loop {
        let (mut hello, mut err) = (None, None);
        tcp.poll(|k, p| {
            heard_any = true;
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
        if let Some(h) = hello {
            return Ok(Heard::Hello(h));
        }
        if term.load(Ordering::Relaxed) {
            return Ok(Heard::Stopped);
        }
        if tcp.closed && !heard_any {
            return Ok(Heard::Dropped);
        }
        if tcp.closed || rt::now_ns() > end {
            bail!("the near side at {} sent no HELLO", a.connect);
        }
        std::thread::sleep(Duration::from_millis(1));
    }
}

/// Tells the near side why this side cannot take the run (set-up failed), and says it here.
fn refuse(tcp: &mut Tcp, why: String) -> Result<(u8, Option<String>)> {
    let line = format!("far side: {why}");
    tcp.send(
        Kind::Exit,
        &[&u32::from(EXIT_SETUP).to_ne_bytes(), line.as_bytes()],
    )?;
    let t = rt::now_ns() + 1_000_000_000;
    while tcp.pending() > 0 && rt::now_ns() < t {
        tcp.flush()?;
        std::thread::sleep(Duration::from_millis(1));
    }
    Ok((EXIT_SETUP, Some(line)))
}

/// One run: HELLO, ports, the far process, the loop, the end.
fn serve(
    a: &Args,
    stream: TcpStream,
    cmd: &[String],
    term: &AtomicBool,
) -> Result<(u8, Option<String>)> {
    let Some((mut tcp, session, hello)) = join(a, stream, term)? else {
        return Ok((
            EXIT_STOPPED,
            Some("interrupted while waiting for the near side's HELLO".into()),
        ));
    };
    if hello.role != a.role {
        return refuse(
            &mut tcp,
            format!(
                "the run at {} puts the {} on this host, and this side joined with --role {} (run `deltaloop join {} --role {}`)",
                a.connect, hello.role, a.role, a.connect, hello.role
            ),
        );
    }
    let plant = a.role == RemoteSide::Plant;
    let mode = hello.mode;
    let dir = match private_dir(&hello.run_id) {
        Ok(d) => d,
        Err(e) => return refuse(&mut tcp, format!("{e:#}")),
    };
    let _tmp = TempDir(dir.clone());
    let config = dir.join("config.toml");
    let cfg = match RunConfig::from_toml_str(&hello.config, None) {
        Ok(c) => c,
        Err(e) => return refuse(&mut tcp, format!("the run's config: {e:#}")),
    };
    let (cfg, said) = this_hosts_placement(cfg, a.role, a.placement);
    if let Some(line) = said {
        eprintln!("deltaloop-bridge: {line}");
        tcp.send(Kind::Log, &[format!("far side: {line}").as_bytes()])?;
    }
    deltaloop_link_setup::files::create_private(&config, cfg.to_toml_string().as_bytes())
        .with_context(|| format!("cannot write {}", config.display()))?;
    let ports = if plant {
        PlantSidePorts::open(&hello.run_id).map(Either::Plant)
    } else {
        Ports::open(&hello.run_id).map(Either::Controller)
    };
    let ports = match ports {
        Ok(p) => p,
        Err(e) => return refuse(&mut tcp, format!("{e:#}")),
    };
    let local = tcp.stream.local_addr()?;
    let udp = UdpSocket::bind(SocketAddr::new(local.ip(), 0))?;
    udp.connect(a.connect)?;
    let port = u64::from(udp.local_addr()?.port());
    let mut far_emu = hello.emulation;
    far_emu.seed = far_emu.seed.wrapping_add(1);
    let mut udp = Udp::sealed(udp, &session, End::Far, far_emu)?;
    let spin_ns = match crate::spin_ns(&config, mode, a.spin_us) {
        Ok(s) => s,
        Err(e) => return refuse(&mut tcp, format!("{e:#}")),
    };
    let law = hello.law.filter(|_| !plant).map(Law::name);
    let (mine, theirs) = deltaloop_transport::handoff::pair()?;
    let child = match spawn(cmd, &hello.run_id, mode, &config, law, &theirs) {
        Ok(c) => c,
        Err(e) => return refuse(&mut tcp, format!("{e:#}")),
    };
    drop(theirs);
    tcp.send(Kind::Ack, &[&port.to_ne_bytes()])?;
    udp.send(Kind::Punch, &[], rt::now_ns())?;
    let wants_relay = cfg
        .link
        .as_ref()
        .is_some_and(|l| l.path == deltaloop_config::LinkPath::Relay);
    let loop_cpu = mode.layout(&cfg).and_then(|l| match a.role {
        RemoteSide::Controller => l.controller_cpu,
        RemoteSide::Plant => l.plant_cpu,
    });
    let mut link = FarLink::new((udp, tcp), child, session, mine, wants_relay, loop_cpu);
    let named = a.controller_cmd.as_ref().and_then(|_| ready_naming(cmd));
    let (code, last) = relay(ports, &mut link, (spin_ns, mode, far_emu), named, term)?;
    std::thread::sleep(ipc::LINGER);
    let line = (!last.is_empty()).then_some(last);
    drop(link);
    let id = hello.run_id.clone();
    ipc::remove_dead_nodes_where(&|n| n.ends_with(&id));
    Ok((code, line))
}

/// The READY text that names a controller of the user's started with `cmd`, as
/// `RunConfig::controller_label` names a local one: the supervisor on the other host labels a
/// foreign controller by its READY text, else by its own config's command, which for a remote
/// controller is the near bridge and names nothing.
fn ready_naming(cmd: &[String]) -> Option<[u8; 160]> {
    let label = deltaloop_config::ControllerSection::command_label(cmd)?;
    Some(ControlMsg::with_text(ControlKind::Ready, Sender::Controller, 0, &label).text)
}

/// Removes the run's temporary folder (its config) when the run is over.
struct TempDir(PathBuf);

/// The prefix of a far bridge's private folder in the temporary directory.
const DIR_PREFIX: &str = "deltaloop-join-";

/// A new folder of this process for run `run_id`, mode 700, under a name no one can guess
/// (regression: the name was `deltaloop-join-<pid>-<run id>`, and a link planted there made
/// `join` write the run's config through it). Never an existing path.
fn private_dir(run_id: &str) -> Result<PathBuf> {
    use std::os::unix::fs::DirBuilderExt;
    let salt: [u8; 8] = crate::seal::random_bytes().map_err(anyhow::Error::msg)?;
    let salt: String = salt.iter().map(|b| format!("{b:02x}")).collect();
    let dir = std::env::temp_dir().join(format!(
        "{DIR_PREFIX}{}-{run_id}-{salt}",
        std::process::id()
    ));
    std::fs::DirBuilder::new()
        .mode(0o700)
        .create(&dir)
        .with_context(|| format!("cannot create {}", dir.display()))?;
    Ok(dir)
}

/// Removes what far bridges killed outright left behind: their private folders (a process that
/// is gone named in the folder's name) and their dead iceoryx2 nodes' resources (regression: a
/// far bridge killed with -9 left 17 entries, 11 MiB, in /dev/shm and its folder, and no later
/// `join` removed them). Says what it removed.
pub fn remove_leftovers() {
    let mut gone = 0;
    if let Ok(rd) = std::fs::read_dir(std::env::temp_dir()) {
        for e in rd.flatten() {
            let name = e.file_name().to_string_lossy().into_owned();
            let Some(pid) = name
                .strip_prefix(DIR_PREFIX)
                .and_then(|r| r.split('-').next())
                .and_then(|p| p.parse::<i32>().ok())
            else {
                continue;
            };
            // SAFETY: kill with signal 0 only asks whether the process exists.
            let alive = unsafe { libc::kill(pid, 0) } == 0
                || std::io::Error::last_os_error().raw_os_error() == Some(libc::EPERM);
            // SAFETY: geteuid has no preconditions.
            let me = unsafe { libc::geteuid() };
            let mine = e
                .metadata()
                .is_ok_and(|m| std::os::unix::fs::MetadataExt::uid(&m) == me);
            if !alive && mine && std::fs::remove_dir_all(e.path()).is_ok() {
                gone += 1;
            }
        }
    }
    let nodes = ipc::remove_dead_nodes();
    if gone > 0 || !nodes.is_empty() {
        eprintln!(
            "deltaloop-bridge: removed what earlier far bridges killed outright left: {gone} folder(s), the iceoryx2 resources of {} dead node(s)",
            nodes.len()
        );
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Regression: the far controller ran at the SCHED_FIFO priority and on the CPU that the
    /// near side's config named (a fake near side chose them). This host's flags, else the
    /// mode's default layout, decide, and a line says what the near side had asked.
    #[test]
    fn regression_the_near_side_cannot_place_the_far_process() {
        let text = "[scenario]\npath = \"s1\"\n[loop.realtime]\ncontroller_cpu = 0\ncontroller_priority = 99\n";
        let cfg = RunConfig::from_toml_str(text, None).unwrap();
        let (c, said) =
            this_hosts_placement(cfg.clone(), RemoteSide::Controller, Placement::default());
        let d = deltaloop_config::Layout::realtime_default();
        assert_eq!(
            (
                c.loop_.realtime.controller_cpu,
                c.loop_.realtime.controller_priority
            ),
            (d.controller_cpu, d.controller_priority)
        );
        let said = said.unwrap();
        assert!(
            said.contains("CPU 0 priority 99 asked by the near side"),
            "{said}"
        );
        let mine = Placement {
            cpu: Some(-1),
            priority: Some(0),
        };
        let (c, _) = this_hosts_placement(cfg.clone(), RemoteSide::Controller, mine);
        assert_eq!(
            (
                c.loop_.realtime.controller_cpu,
                c.loop_.realtime.controller_priority
            ),
            (Some(-1), Some(0))
        );
        assert_eq!(
            c.loop_.realtime.plant_cpu, cfg.loop_.realtime.plant_cpu,
            "not ours"
        );
        // A config that asks nothing of it says nothing.
        let plain = RunConfig::from_toml_str("[scenario]\npath = \"s1\"\n", None).unwrap();
        assert_eq!(
            this_hosts_placement(plain, RemoteSide::Plant, Placement::default()).1,
            None
        );
    }

    /// Regression: the far bridge's folder was `deltaloop-join-<pid>-<run id>`, so a link planted
    /// at that path made `join` write the run's config through it. The folder is new, private
    /// (mode 700) and named with 64 random bits; two for the same run never collide.
    #[test]
    fn regression_the_far_folder_is_new_private_and_unguessable() {
        use std::os::unix::fs::PermissionsExt;
        let a = private_dir("r1").unwrap();
        let b = private_dir("r1").unwrap();
        assert_ne!(a, b);
        let mode = std::fs::metadata(&a).unwrap().permissions().mode() & 0o777;
        assert_eq!(mode, 0o700);
        let name = a.file_name().unwrap().to_string_lossy().into_owned();
        assert!(name.starts_with(&format!("{DIR_PREFIX}{}-r1-", std::process::id())));
        // A config written there never follows a link planted at its name.
        let target = a.join("elsewhere");
        std::os::unix::fs::symlink(&target, b.join("config.toml")).unwrap();
        assert!(deltaloop_link_setup::files::create_private(&b.join("config.toml"), b"x").is_err());
        assert!(!target.exists());
        for d in [a, b] {
            std::fs::remove_dir_all(d).unwrap();
        }
    }

    /// Regression: a far bridge killed with -9 left its folder behind for good. The next one
    /// removes the folders of processes that are gone, and only those.
    #[test]
    fn regression_leftover_folders_of_dead_far_bridges_are_removed() {
        // A pid that is not running: past the largest pid the kernel hands out.
        let dead = std::env::temp_dir().join(format!("{DIR_PREFIX}{}-r-00", i32::MAX - 7));
        let live = private_dir("r").unwrap();
        std::fs::create_dir_all(&dead).unwrap();
        remove_leftovers();
        assert!(!dead.exists());
        assert!(live.exists());
        std::fs::remove_dir_all(live).unwrap();
    }
}
