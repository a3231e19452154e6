//! The process modes: one `deltaloop-plant` + `deltaloop-controller` pair per law, over iceoryx2.
//!
//! [`run_law`] goes through four phases: spawn the pair (found next to the supervisor's own
//! executable), the handshake (READY from both, the first chunks of the joint reference to the
//! controller, ARMED, START), observe (drain large queues every millisecond, send the reference
//! ahead of the loop; never notify or wait on the loop) until both children exit, and classify
//! how they ended. While it observes, every finished tick goes through the same
//! [`Recorder`](crate::record::Recorder) the in-process loop fills (so every row and metric comes
//! from the same code) and on to disk: memory does not grow with the run.

use crate::loops::feed::ReferenceFeed;
use crate::loops::lawrun::{self, Keep, LawRecorder, LawRun};
use crate::loops::peer_text::{self, Tail};
use crate::record::Fault;
use crate::study::Study;
use crate::timing::{PeakRss, Seen, Timing, TimingAcc, TimingCsv};
use anyhow::{Context, Result, anyhow, bail};
use deltaloop_config::config::Layout;
use deltaloop_config::{Law, LoopMode, RunConfig};
use deltaloop_transport::ipc::{self, IpcContext, OBSERVER_BUFFER, Svc};
use deltaloop_transport::rt;
use deltaloop_transport::wire::{
    self, ControlKind, ControlMsg, Sender, StateMsg, TelemetryMsg, TorqueMsg,
};
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;
use iceoryx2::service::header::payload_header::PayloadHeader;
use std::cell::Cell;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Stdio};
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;

/// What one law's process run produced.
pub struct ProcessRun {
    /// A loop fault (a child died, stalled, or the plant stopped).
    pub fault: Option<Fault>,
    /// Ctrl-C / SIGTERM stopped the run.
    pub interrupted: bool,
    /// The run id that scoped this pair's iceoryx2 services and nodes.
    pub run_id: String,
    pub run: LawRun,
    pub timing: Timing,
    /// Warnings and errors the children printed (one line each).
    pub child_messages: Vec<String>,
}

/// How messages name a process.
fn role(who: Sender) -> &'static str {
    match who {
        Sender::Plant => "plant",
        Sender::Controller => "controller",
        Sender::Supervisor => "supervisor",
    }
}

/// Where the child executables are: next to the running one.
pub fn exe_dir() -> Result<PathBuf> {
    let exe = std::env::current_exe().context("cannot locate the deltaloop executable")?;
    Ok(exe.parent().map(Path::to_path_buf).unwrap_or_default())
}

/// A run id unique on this machine: pid, a per-process counter and the clock.
pub fn new_run_id() -> String {
    static N: AtomicU64 = AtomicU64::new(0);
    format!(
        "{:x}-{:x}-{:x}",
        std::process::id(),
        N.fetch_add(1, Ordering::Relaxed),
        rt::now_ns() & 0xffff_ffff
    )
}

/// A child process, reaped with its resource usage (wait4), and killed and reaped on drop, so
/// no process outlives the run, whatever happens.
struct Reaped {
    child: Option<Child>,
    who: Sender,
    status: Option<ExitStatus>,
    /// Its peak resident set size, KiB, once it has exited.
    peak_rss_kib: Option<u64>,
}

impl Reaped {
    fn new(child: Child, who: Sender) -> Self {
        Self {
            child: Some(child),
            who,
            status: None,
            peak_rss_kib: None,
        }
    }

    /// Its exit status, if it has exited (reaps it then).
    fn exited(&mut self) -> Option<ExitStatus> {
        use std::os::unix::process::ExitStatusExt;
        if self.status.is_none()
            && let Some(c) = &self.child
        {
            let (mut st, mut ru) = (0i32, std::mem::MaybeUninit::<libc::rusage>::zeroed());
            // SAFETY: waiting for our own child, without blocking; both pointers are valid.
            let r = unsafe { libc::wait4(c.id() as i32, &mut st, libc::WNOHANG, ru.as_mut_ptr()) };
            if r == c.id() as i32 {
                self.status = Some(ExitStatus::from_raw(st));
                // SAFETY: wait4 filled it (it returned the pid).
                self.peak_rss_kib = Some(unsafe { ru.assume_init() }.ru_maxrss as u64);
            }
        }
        self.status
    }
}

impl Drop for Reaped {
    fn drop(&mut self) {
        if self.exited().is_some() {
            return;
        }
        let Some(pid) = self.child.as_ref().map(|c| c.id() as i32) else {
            return;
        };
        // Ask politely first; then make sure.
        // SAFETY: sending SIGTERM to our own child, which has not been reaped.
        unsafe { libc::kill(pid, libc::SIGTERM) };
        for _ in 0..200 {
            if self.exited().is_some() {
                return;
            }
            std::thread::sleep(Duration::from_millis(5));
        }
        if let Some(mut c) = self.child.take() {
            let _ = c.kill();
            let _ = c.wait();
        }
    }
}

/// The supervisor's own peak resident set size so far, KiB.
fn own_peak_rss_kib() -> u64 {
    let mut ru = std::mem::MaybeUninit::<libc::rusage>::zeroed();
    // SAFETY: getrusage fills the struct we own.
    if unsafe { libc::getrusage(libc::RUSAGE_SELF, ru.as_mut_ptr()) } != 0 {
        return 0;
    }
    // SAFETY: filled by the successful call.
    unsafe { ru.assume_init() }.ru_maxrss as u64
}

/// What to execute for one child: a program and the arguments that come before the standard
/// ones.
struct Launch {
    program: PathBuf,
    args: Vec<String>,
    /// The user's own command (not the built-in executable).
    custom: bool,
}

impl Launch {
    /// The config's `command` if it has one, else the built-in `name` in `dir`.
    fn of(command: &[String], dir: &Path, name: &str) -> Self {
        match command.split_first() {
            Some((program, args)) => Self {
                program: PathBuf::from(program),
                args: args.to_vec(),
                custom: true,
            },
            None => Self {
                program: dir.join(name),
                args: Vec::new(),
                custom: false,
            },
        }
    }

    /// The command line as the user would type it.
    fn shown(&self) -> String {
        std::iter::once(self.program.display().to_string())
            .chain(self.args.iter().cloned())
            .collect::<Vec<_>>()
            .join(" ")
    }
}

fn spawn(launch: &Launch, args: &[String], log: &Path, who: Sender) -> Result<Reaped> {
    let err =
        std::fs::File::create(log).with_context(|| format!("cannot create {}", log.display()))?;
    let mut cmd = Command::new(&launch.program);
    cmd.args(&launch.args)
        .args(args)
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(err);
    // The terminal's Ctrl-C and hang-up reach the whole process group, and may come before the
    // child has set up its own signal handling: it starts with both ignored (kept across exec),
    // and the supervisor stops it in order.
    // A supervisor killed outright (SIGKILL, the OOM killer) cannot stop its children: the kernel
    // sends them SIGTERM then, and they stop as they would on STOP (regression: a SIGKILLed
    // supervisor left its plant running to the scenario's end, a soak's up to 24 h).
    let parent = std::process::id() as libc::pid_t;
    // SAFETY: signal(), prctl() and getppid() are async-signal-safe; nothing else runs between
    // fork and exec.
    unsafe {
        use std::os::unix::process::CommandExt;
        cmd.pre_exec(move || {
            libc::signal(libc::SIGINT, libc::SIG_IGN);
            libc::signal(libc::SIGHUP, libc::SIG_IGN);
            libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGTERM);
            // The supervisor died before the line above: do not start an orphan.
            if libc::getppid() != parent {
                return Err(std::io::Error::other("the supervisor is gone"));
            }
            Ok(())
        });
    }
    let child = cmd.spawn().with_context(|| {
        if launch.custom {
            format!(
                "cannot start the {} command `{}` ({}.command)",
                role(who),
                launch.shown(),
                role(who)
            )
        } else {
            format!(
                "cannot start {} (expected next to deltaloop: build all binaries with `cargo build --release`)",
                launch.program.display()
            )
        }
    })?;
    Ok(Reaped::new(child, who))
}

/// Whether process `pid` is `root` or one of its descendants (a child started through a wrapper
/// script publishes from a grandchild of the supervisor), from `/proc/<pid>/stat`.
fn in_process_tree(pid: u32, root: u32) -> bool {
    let mut p = pid;
    // A process tree deeper than this is no wrapper of ours.
    for _ in 0..32 {
        if p == root {
            return true;
        }
        let Ok(stat) = std::fs::read_to_string(format!("/proc/{p}/stat")) else {
            return false;
        };
        // `pid (comm) state ppid …`: comm may hold spaces and parentheses; ppid follows the last ')'.
        let ppid = stat
            .rsplit_once(')')
            .and_then(|(_, rest)| rest.split_whitespace().nth(1))
            .and_then(|v| v.parse::<u32>().ok());
        match ppid {
            Some(pp) if pp > 1 => p = pp,
            _ => return false,
        }
    }
    false
}

/// What one child says, on its own control service, believed only from that child: the first
/// publisher seen there must belong to the child's process (or a descendant of it), and after it
/// only that publisher is heard. The service has one publisher slot, so once the child holds it
/// no other process can publish there; if another process took it first, the run is refused.
struct ControlIn {
    sub: Subscriber<Svc, ControlMsg, ()>,
    who: Sender,
    /// The child's pid, once it is spawned.
    root: Cell<Option<u32>>,
    /// The child's publisher, once its first message proved it.
    publisher: Cell<Option<iceoryx2::identifiers::UniquePublisherId>>,
    /// The first process not the child's that published here (pid; 0 if its pid is unknown).
    intruder: Cell<Option<u32>>,
}

impl ControlIn {
    fn open(node: &Node<Svc>, run_id: &str, who: Sender) -> Result<Self> {
        Ok(Self {
            sub: ipc::control(node, run_id, who)?
                .subscriber_builder()
                .create()
                .ipc(format!("subscriber on {}", ipc::control_service(who)))?,
            who,
            root: Cell::new(None),
            publisher: Cell::new(None),
            intruder: Cell::new(None),
        })
    }

    /// The kinds `who` may send.
    fn allowed(&self, kind: ControlKind) -> bool {
        use ControlKind::*;
        match self.who {
            Sender::Plant => matches!(kind, Ready | Fault | Diverged | Stopped),
            Sender::Controller => matches!(kind, Ready | Armed),
            Sender::Supervisor => false,
        }
    }

    /// The next message the child itself sent, of a kind it may send; everything else is dropped
    /// (and a foreign publisher remembered).
    fn receive(&self) -> Result<Option<ControlMsg>> {
        while let Some(sample) = self.sub.receive().ipc("receive control")? {
            let origin = sample.origin();
            let trusted = match (self.publisher.get(), self.root.get()) {
                (Some(id), _) => id == origin,
                (None, Some(root)) => {
                    let pid = sample
                        .header()
                        .node_id()
                        .pid::<Svc>()
                        .map_or(0, |p| p.value() as u32);
                    let ok = pid != 0 && in_process_tree(pid, root);
                    if ok {
                        self.publisher.set(Some(origin));
                    } else if self.intruder.get().is_none() {
                        self.intruder.set(Some(pid));
                    }
                    ok
                }
                (None, None) => false,
            };
            let m = *sample.payload();
            if trusted && m.sender() == Some(self.who) && m.kind().is_some_and(|k| self.allowed(k))
            {
                return Ok(Some(m));
            }
        }
        Ok(None)
    }

    /// One line about a process that published on this child's service, if one did.
    fn intrusion(&self) -> Option<String> {
        let pid = self.intruder.get()?;
        let who = role(self.who);
        let cmd = std::fs::read(format!("/proc/{pid}/cmdline"))
            .map(|c| {
                let c = String::from_utf8_lossy(&c).replace('\0', " ");
                wire::escape_peer_text(c.trim())
            })
            .unwrap_or_default();
        Some(format!(
            "a process that is not the {who} (pid {pid}{}{cmd}{}) published on the {who}'s control service `{}`; its messages were ignored: only the {who} may speak there",
            if cmd.is_empty() { "" } else { ", `" },
            if cmd.is_empty() { "" } else { "`" },
            ipc::control_service(self.who),
        ))
    }
}

/// The supervisor's ports: observers of the three loop streams, run control (the reference
/// publisher is a [`ReferenceFeed`] on the same node).
struct Observer {
    state: Subscriber<Svc, StateMsg, ()>,
    torque: Subscriber<Svc, TorqueMsg, ()>,
    telemetry: Subscriber<Svc, TelemetryMsg, ()>,
    /// START and STOP: the only publisher of `control`, taken before the children start.
    control: Publisher<Svc, ControlMsg, ()>,
    from_plant: ControlIn,
    from_controller: ControlIn,
    node: Node<Svc>,
}

impl Observer {
    fn open(run_id: &str) -> Result<Self> {
        let node = ipc::node("supervisor", run_id)?;
        Ok(Self {
            state: ipc::state(&node, run_id)?
                .subscriber_builder()
                .buffer_size(OBSERVER_BUFFER)
                .create()
                .ipc("state observer")?,
            torque: ipc::torque(&node, run_id)?
                .subscriber_builder()
                .buffer_size(OBSERVER_BUFFER)
                .create()
                .ipc("torque observer")?,
            telemetry: ipc::telemetry(&node, run_id)?
                .subscriber_builder()
                .buffer_size(OBSERVER_BUFFER)
                .create()
                .ipc("telemetry observer")?,
            control: ipc::control(&node, run_id, Sender::Supervisor)?
                .publisher_builder()
                .create()
                .ipc("control publisher")?,
            from_plant: ControlIn::open(&node, run_id, Sender::Plant)?,
            from_controller: ControlIn::open(&node, run_id, Sender::Controller)?,
            node,
        })
    }

    /// The children's pids: from now on their control services are believed only from them.
    fn trust(&self, pair: &Pair) {
        for (c, child) in [
            (&self.from_plant, &pair.plant),
            (&self.from_controller, &pair.controller),
        ] {
            c.root.set(child.child.as_ref().map(Child::id));
        }
    }

    /// The next message of either child (the plant's first).
    fn receive(&self) -> Result<Option<ControlMsg>> {
        match self.from_plant.receive()? {
            Some(m) => Ok(Some(m)),
            None => self.from_controller.receive(),
        }
    }

    /// Lines about processes that published on a child's control service.
    fn intrusions(&self) -> Vec<String> {
        [&self.from_plant, &self.from_controller]
            .iter()
            .filter_map(|c| c.intrusion())
            .collect()
    }

    /// Sends STOP to both children.
    fn stop(&self) {
        let _ = self
            .control
            .send_copy(ControlMsg::new(ControlKind::Stop, Sender::Supervisor));
    }
}

/// The two children of one run and their stderr logs.
struct Pair {
    plant: Reaped,
    controller: Reaped,
    logs: Logs,
    /// The plant's and the controller's command lines, for messages.
    shown: (String, String),
}

/// The children's stderr logs.
#[derive(Clone)]
struct Logs {
    plant: PathBuf,
    controller: PathBuf,
}

impl Logs {
    /// The last lines both children printed (at most [`peer_text::MAX_LINES`] each, read from
    /// the end of their logs, sanitized; a first line says where earlier ones are).
    fn messages(&self) -> Vec<String> {
        let mut m = Tail::read(&self.plant).last_lines(peer_text::MAX_LINES, &self.plant);
        m.extend(Tail::read(&self.controller).last_lines(peer_text::MAX_LINES, &self.controller));
        m
    }

    /// What each child said last, for a one-line error: `the plant: …; the controller: …`
    /// (children that said nothing are left out).
    fn said(&self) -> String {
        [("plant", &self.plant), ("controller", &self.controller)]
            .iter()
            .filter_map(|(who, p)| {
                let r = Tail::read(p).reason();
                (!r.is_empty()).then(|| format!("the {who}: {r} (log: {})", p.display()))
            })
            .collect::<Vec<_>>()
            .join("; ")
    }
}

impl Pair {
    /// Starts both children with the run id, the resolved config and the mode: the built-in
    /// executables next to `deltaloop`, or the config's `command`s in their place.
    fn spawn(
        run_id: &str,
        law: Law,
        mode: LoopMode,
        run_dir: &Path,
        cfg: &RunConfig,
    ) -> Result<Self> {
        let exe = exe_dir()?;
        let common = vec![
            "--run-id".to_string(),
            run_id.to_string(),
            "--config".into(),
            run_dir.join("config.toml").display().to_string(),
            "--mode".into(),
            mode.name().into(),
        ];
        let plant_log = run_dir.join(format!("{law}.plant.log"));
        let ctrl_log = run_dir.join(format!("{law}.controller.log"));
        let (pl, cl) = (
            Launch::of(&cfg.plant.command, &exe, "deltaloop-plant"),
            Launch::of(&cfg.controller.command, &exe, "deltaloop-controller"),
        );
        let plant = spawn(&pl, &common, &plant_log, Sender::Plant)?;
        let mut ctrl_args = common;
        ctrl_args.extend(["--law".to_string(), law.name().to_string()]);
        let controller = spawn(&cl, &ctrl_args, &ctrl_log, Sender::Controller)?;
        Ok(Self {
            plant,
            controller,
            logs: Logs {
                plant: plant_log,
                controller: ctrl_log,
            },
            shown: (pl.shown(), cl.shown()),
        })
    }

    /// Fails, with the children's stderr, if either child has exited.
    fn check_alive(&mut self) -> Result<()> {
        for child in [&mut self.plant, &mut self.controller] {
            if let Some(status) = child.exited() {
                let who = role(child.who);
                let said = self.logs.said();
                bail!(
                    "{who} {} before the run started{}{said}",
                    status_text(status),
                    if said.is_empty() { "" } else { ": " }
                );
            }
        }
        Ok(())
    }
}

/// Polls the control channel until `done` says a handshake step is complete (Ok(true)), failing
/// (with the children's stderr) if a child exits first or the handshake timeout passes. Ok(false)
/// if Ctrl-C / SIGTERM / SIGHUP arrived first.
fn await_control(
    obs: &Observer,
    pair: &mut Pair,
    step: &dyn Fn() -> String,
    done: &mut dyn FnMut(&ControlMsg) -> bool,
) -> Result<bool> {
    let deadline = rt::now_ns() + ipc::HANDSHAKE_TIMEOUT_NS;
    loop {
        while let Some(m) = obs.receive()? {
            if done(&m) {
                return Ok(true);
            }
        }
        if let Some(i) = obs.intrusions().into_iter().next() {
            bail!("{i}");
        }
        if crate::loops::signals::interrupted() {
            return Ok(false);
        }
        pair.check_alive()?;
        if rt::now_ns() > deadline {
            let said = pair.logs.said();
            bail!(
                "{} within {} s{}{said}",
                step(),
                ipc::HANDSHAKE_TIMEOUT_NS / 1_000_000_000,
                if said.is_empty() { "" } else { ": " }
            );
        }
        std::thread::sleep(Duration::from_micros(200));
    }
}

/// READY from both children, the first chunks of the reference to the controller, ARMED from it.
/// Ok(false) if the run was interrupted first.
fn handshake(
    obs: &Observer,
    feed: &mut ReferenceFeed,
    pair: &mut Pair,
    study: &Study,
) -> Result<bool> {
    let pair_shown = pair.shown.clone();
    let ready_from = [std::cell::Cell::new(false), std::cell::Cell::new(false)];
    let silent = || {
        let who: Vec<String> = [
            (Sender::Plant, &pair_shown.0),
            (Sender::Controller, &pair_shown.1),
        ]
        .iter()
        .zip(&ready_from)
        .filter(|(_, r)| !r.get())
        .map(|((w, cmd), _)| format!("the {} (`{cmd}`)", role(*w)))
        .collect();
        format!("{} never said READY", who.join(" and "))
    };
    let ready = await_control(obs, pair, &silent, &mut |m| {
        match (m.kind(), m.sender()) {
            (Some(ControlKind::Ready), Some(Sender::Plant)) => ready_from[0].set(true),
            (Some(ControlKind::Ready), Some(Sender::Controller)) => ready_from[1].set(true),
            _ => {}
        }
        ready_from.iter().all(std::cell::Cell::get)
    })?;
    if !ready {
        return Ok(false);
    }
    feed.send_initial(&study.reference)?;
    let unarmed = || {
        format!(
            "the controller (`{}`) never said ARMED (it takes the reference first)",
            pair_shown.1
        )
    };
    await_control(obs, pair, &unarmed, &mut |m| {
        m.kind() == Some(ControlKind::Armed)
    })
}

/// Ticks the observer holds open at most (a ring indexed by tick).
const WINDOW: u64 = 32_768;

/// A tick is finished once the loop has been seen this far past it (2.5 s at Ts = 0.3 ms): a
/// reply up to that late is still filed with its tick (and shows as late).
const LAG: u64 = 8_192;

/// The open ticks, a ring of [`WINDOW`] slots.
struct Window {
    slots: Vec<Seen>,
    /// The next tick to finish.
    next: u64,
    /// The last tick kept (N + 1: the state after the run).
    last: u64,
}

impl Window {
    fn new(last: u64) -> Self {
        let empty = Seen {
            k: u64::MAX,
            ..Seen::default()
        };
        Self {
            slots: vec![empty; WINDOW as usize],
            next: 0,
            last,
        }
    }

    /// The slot of tick k (cleared if it held an older tick).
    fn slot(&mut self, k: u64) -> &mut Seen {
        let s = &mut self.slots[(k % WINDOW) as usize];
        if s.k != k {
            *s = Seen {
                k,
                ..Seen::default()
            };
        }
        s
    }

    /// Takes the next tick out of the window.
    fn take(&mut self) -> Seen {
        let k = self.next;
        self.next += 1;
        let s = &mut self.slots[(k % WINDOW) as usize];
        let seen = if s.k == k {
            *s
        } else {
            Seen {
                k,
                ..Seen::default()
            }
        };
        s.k = u64::MAX;
        seen
    }
}

/// Everything the supervisor does with the loop's streams while they arrive: file each message
/// by tick in the window, and hand every finished tick, in order, to `<law>.timing.csv`, the
/// timing histograms and the recorder (trace and metrics). Memory is fixed at START.
struct Observation<'a> {
    window: Window,
    rec: LawRecorder<'a>,
    timing: TimingAcc,
    /// `<law>.timing.csv`, unless `record.timing_csv = false`.
    csv: Option<TimingCsv>,
    /// The last tick with a loop message (state, reply, or telemetry of the loop, not of the
    /// safe stop after it).
    last_seen: Option<u64>,
    /// The newest reply seen (the controller has answered up to its tick).
    last_torque: Option<TorqueMsg>,
    /// The newest telemetry of the loop seen.
    last_tel: Option<TelemetryMsg>,
    /// The plant's FAULT: it stopped the loop at this tick (and braked).
    plant_fault: Option<Fault>,
    /// The plant's DIVERGED: its model failed at this tick.
    diverged: Option<Fault>,
    /// The first tick since the last complete one that was not complete: a loss if the loop
    /// shows up again later, else where the run ended.
    gap: Option<u64>,
    /// The recorder stopped (the divergence rule).
    stopped: bool,
    /// The first tick whose reply carried a non-finite torque: the run diverged there (the
    /// recorder will say so when it gets to it), so the loop is stopped now, not 2.5 s later.
    non_finite: Option<u64>,
    /// Replies for a tick that already had one (only the first is kept: the plant applies it).
    duplicate_replies: u64,
    /// The tick of the first state with `STATE_FINAL` (N + 1 after a complete run).
    final_tick: Option<u64>,
    /// The state after the last tick, N + 1.
    after: Option<StateMsg>,
}

fn max_opt(a: Option<u64>, b: u64) -> Option<u64> {
    Some(a.map_or(b, |a| a.max(b)))
}

impl<'a> Observation<'a> {
    fn new(rec: LawRecorder<'a>, timing: TimingAcc, csv: Option<TimingCsv>) -> Self {
        Self {
            window: Window::new(timing.last_tick() + 1),
            rec,
            timing,
            csv,
            last_seen: None,
            last_torque: None,
            last_tel: None,
            plant_fault: None,
            diverged: None,
            gap: None,
            stopped: false,
            non_finite: None,
            duplicate_replies: 0,
            final_tick: None,
            after: None,
        }
    }

    /// Takes everything waiting on the observer's ports, and finishes the ticks the loop has
    /// left [`LAG`] behind.
    fn drain(&mut self, obs: &Observer) -> Result<()> {
        while let Some(s) = obs.state.receive().ipc("observe state")? {
            let m = *s.payload();
            if m.flags & wire::STATE_FINAL != 0 && self.final_tick.is_none() {
                self.final_tick = Some(m.tick);
            }
            if self.open(m.tick)? {
                self.window.slot(m.tick).state = Some(m);
                self.last_seen = max_opt(self.last_seen, m.tick);
            }
        }
        while let Some(s) = obs.torque.receive().ipc("observe torque")? {
            let m = *s.payload();
            if self.open(m.tick)? {
                // The first reply is the one the plant applied (a second one for the same tick
                // is dropped by it): keep that one (regression: the trace recorded the second,
                // and replay disagreed with the run).
                let slot = self.window.slot(m.tick);
                if slot.torque.is_none() {
                    slot.torque = Some(m);
                } else {
                    self.duplicate_replies += 1;
                }
                self.last_seen = max_opt(self.last_seen, m.tick);
                if m.tau.iter().any(|x| !x.is_finite()) && m.tick < self.window.last {
                    self.non_finite.get_or_insert(m.tick);
                }
            }
            if self.last_torque.is_none_or(|t| t.tick < m.tick) {
                self.last_torque = Some(m);
            }
        }
        while let Some(s) = obs.telemetry.receive().ipc("observe telemetry")? {
            let m = *s.payload();
            let in_loop = m.flags & wire::TEL_SAFE_STOP == 0;
            if self.open(m.tick)? {
                self.window.slot(m.tick).tel = Some(m);
                if in_loop {
                    self.last_seen = max_opt(self.last_seen, m.tick);
                }
            }
            if in_loop && self.last_tel.is_none_or(|t| t.tick < m.tick) {
                self.last_tel = Some(m);
            }
        }
        while let Some(m) = obs.from_plant.receive()? {
            let m = &m;
            let fault = || Fault {
                tick: m.tick,
                cause: m.text(),
            };
            match m.kind() {
                Some(ControlKind::Diverged) if self.diverged.is_none() => {
                    self.diverged = Some(fault())
                }
                Some(ControlKind::Fault) if self.plant_fault.is_none() => {
                    self.plant_fault = Some(fault())
                }
                _ => {}
            }
        }
        while let Some(seen) = self.last_seen
            && self.window.next + LAG <= seen
        {
            let t = self.window.take();
            self.finish_tick(t)?;
        }
        Ok(())
    }

    /// Whether tick k goes into the window; makes room for it by finishing the oldest ticks (a
    /// tick already finished, or beyond the run, is dropped).
    fn open(&mut self, k: u64) -> Result<bool> {
        if k > self.window.last || k < self.window.next {
            return Ok(false);
        }
        while k >= self.window.next + WINDOW {
            let t = self.window.take();
            self.finish_tick(t)?;
        }
        Ok(true)
    }

    /// The ticks the controller has answered (the reference it no longer needs).
    fn answered(&self) -> Option<u64> {
        self.last_torque.map(|t| t.tick)
    }

    /// One finished tick to the timing file, the histograms and the recorder.
    fn finish_tick(&mut self, seen: Seen) -> Result<()> {
        if let Some(csv) = &mut self.csv {
            csv.write(&seen)?;
        }
        self.timing.push(seen)?;
        crate::loops::tick_hook::call(&seen);
        if seen.k == self.window.last {
            self.after = seen.state;
            return Ok(());
        }
        if self.stopped {
            return Ok(());
        }
        let in_loop = seen.tel.filter(|m| m.flags & wire::TEL_SAFE_STOP == 0);
        // A tick without telemetry never ran to its end (or the sample was lost), unless the
        // plant's telemetry says it held through a missing reply.
        let ran = in_loop.is_some() || seen.torque.is_some();
        let Some(state) = seen.state.filter(|_| ran) else {
            self.gap.get_or_insert(seen.k);
            return Ok(());
        };
        // The loop went on after a hole: the hole is a loss, not an end (regression: the
        // supervisor stopped for 3 s lost part of the stream, and the run was called a divergence
        // at the first hole, dropping every good tick after it).
        if let Some(g) = self.gap.take() {
            (g..seen.k).for_each(|j| self.rec.lost(j));
        }
        if !self.rec.tick(&state, seen.torque.as_ref()) {
            self.stopped = true;
            return Ok(());
        }
        // The plant's model failed integrating this tick: it sent no telemetry, as in-process.
        let failed = self.diverged.as_ref().filter(|d| d.tick == seen.k + 1);
        if in_loop.is_some() || failed.is_none() {
            self.rec.applied(in_loop.as_ref());
        }
        if let Some(d) = failed {
            self.rec.plant_failed(d.cause.clone());
            self.stopped = true;
        }
        Ok(())
    }

    /// After both children are gone: finishes every tick left, decides where and why the
    /// stream ended, and returns the run and its timing.
    fn finish(mut self, interrupted: bool, cause: Option<&Fault>) -> Result<(LawRun, Timing)> {
        if let Some(f) = cause {
            self.rec.fault(f.clone());
        }
        self.rec.duplicate_replies(self.duplicate_replies);
        // Past the newest loop tick seen, a stopped run's window is empty up to N + 1: those
        // ticks never ran, and only the first of them (where the loop stopped) and N + 1 go on
        // (regression: an interrupted soak counted thousands of them as lost samples and ticks).
        let stop = self.last_seen.map_or(0, |k| k + 1);
        while self.window.next <= self.window.last {
            let t = self.window.take();
            let empty = t.state.is_none() && t.torque.is_none() && t.tel.is_none();
            if empty && t.k > stop && t.k < self.window.last {
                continue;
            }
            self.finish_tick(t)?;
        }
        if let Some(csv) = self.csv {
            csv.finish()?;
        }
        let timing = self.timing.finish()?;
        let mut rec = self.rec;
        let n = self.window.last - 1;
        let mut after = self.after.filter(|_| !self.stopped);
        if let (Some(g), false) = (self.gap, self.stopped) {
            // Incomplete ticks before the last tick seen were lost; the first one after it is
            // where the loop stopped.
            let seen = self.last_seen.unwrap_or(0);
            (g..seen.min(n + 1)).for_each(|j| rec.lost(j));
            if seen <= n {
                let k = g.max(seen);
                after = None;
                if interrupted {
                    rec.interrupt();
                } else if cause.is_none() {
                    let why = match &self.diverged {
                        Some(d) if d.tick <= k + 1 => d.cause.clone(),
                        _ => format!("the supervisor lost tick {k} of the stream"),
                    };
                    if k == 0 {
                        bail!("{why}");
                    }
                    rec.plant_failed(why);
                }
            }
        }
        Ok((lawrun::finish(rec, after.as_ref())?, timing))
    }
}

/// How the observed run ended.
struct Ending {
    plant: Option<ExitStatus>,
    controller: Option<ExitStatus>,
    /// When the first child exited while the other still ran, and which.
    first_exit: Option<(u64, Sender)>,
    /// The supervisor sent STOP (Ctrl-C / SIGTERM).
    interrupted: bool,
    /// The supervisor sent STOP because the run diverged (the record ended by the divergence
    /// rule): the run's status is the divergence, not a fault or an interruption.
    diverged_stop: bool,
}

/// Observes until both children exit (or the bounded waits after a STOP or one child's exit run
/// out), filing every message by tick.
fn observe(
    obs: &Observer,
    feed: &mut ReferenceFeed,
    pair: &mut Pair,
    study: &Study,
    streams: &mut Observation<'_>,
) -> Result<Ending> {
    let cfg = &study.config;
    let n = study.reference.n as u64;
    let ts_ns = (cfg.loop_.ts_s * 1e9).round() as u64;
    // Bounded waits: after STOP, or after one child exits early, the other gets the safe stop
    // (plus the silence timeout for the plant to notice a dead controller), then it is stopped.
    // The overall limit leaves room for the whole safe stop too (regression: a 60 s safe stop
    // was cut off after 14 s, and the plant's reason with it).
    let silence_ns = u64::from(cfg.loop_.silence_timeout_ms) * 1_000_000;
    let grace_ns = u64::from(cfg.faults.safe_stop_ms) * 1_000_000 + 2_000_000_000;
    let expected_ns = (n + 2) * ts_ns * 20 + 10_000_000_000;
    let give_up = rt::now_ns() + expected_ns.max(silence_ns * 3) + silence_ns + grace_ns;
    let mut stop_sent: Option<u64> = None;
    let mut diverged_stop = false;
    let mut first_exit: Option<(u64, Sender)> = None;
    loop {
        streams.drain(obs)?;
        if let Some(a) = streams.answered() {
            feed.feed(&study.reference, a)?;
        }
        let (p, c) = (pair.plant.exited(), pair.controller.exited());
        let now = rt::now_ns();
        if first_exit.is_none() {
            first_exit = match (p.is_some(), c.is_some()) {
                (false, true) => Some((now, Sender::Controller)),
                (true, false) => Some((now, Sender::Plant)),
                _ => None,
            };
        }
        if p.is_some() && c.is_some() {
            break;
        }
        // Ctrl-C, or the divergence rule ended the record: stop the loop (the plant brakes)
        // rather than let it run on to the scenario's end (regression: a realtime soak whose
        // robot diverged after 2 minutes ran on for the rest of its hour, unrecorded).
        let interrupted = crate::loops::signals::interrupted();
        let diverged = streams.stopped || streams.non_finite.is_some();
        if (interrupted || diverged) && stop_sent.is_none() {
            obs.stop();
            stop_sent = Some(now);
            diverged_stop = !interrupted;
        }
        let waited_out = match first_exit {
            // The plant is gone. If it exited by itself it released the controller with a final
            // state: give the controller 1 s to finish and say why. If it was killed by a signal
            // nothing will release the controller: stop it now.
            Some((t, Sender::Plant)) => {
                use std::os::unix::process::ExitStatusExt;
                let killed = p.is_some_and(|s| s.signal().is_some());
                now > t + if killed { 20_000_000 } else { 1_000_000_000 }
            }
            // A dead controller: the plant notices, holds, brakes, and exits by itself.
            Some((t, _)) => now > t + silence_ns + grace_ns,
            None => false,
        };
        if waited_out || stop_sent.is_some_and(|t| now > t + grace_ns) || now > give_up {
            break;
        }
        std::thread::sleep(Duration::from_millis(1));
    }
    streams.drain(obs)?;
    Ok(Ending {
        plant: pair.plant.exited(),
        controller: pair.controller.exited(),
        first_exit,
        interrupted: stop_sent.is_some() && !diverged_stop,
        diverged_stop,
    })
}

/// Runs `law` over the study with a real process pair. `run_dir` holds the resolved config the
/// children read and receives their stderr logs and `<law>.timing.csv`; `keep` says where the
/// trace goes.
pub fn run_law(
    study: &Study,
    law: Law,
    mode: LoopMode,
    run_dir: &Path,
    keep: &Keep,
) -> Result<ProcessRun> {
    let cfg = &study.config;
    let Some(layout) = mode.layout(cfg) else {
        bail!("mode {mode} runs no processes");
    };
    // A full /dev/shm would kill a child with SIGBUS mid-set-up: say so up front instead.
    if let Some(free) = ipc::shm_free_bytes() {
        ipc::check_shm(ipc::shm_needed_bytes(), free).map_err(|e| anyhow!(e))?;
    }
    let rid = new_run_id();
    let obs = Observer::open(&rid)?;
    let lead = match mode {
        LoopMode::Lockstep => crate::loops::feed::LOCKSTEP_LEAD_CHUNKS,
        _ => ipc::REF_RING as u64,
    };
    let mut feed = ReferenceFeed::create(&obs.node, &rid, study.reference.row_count(), lead)?;
    let mut pair = Pair::spawn(&rid, law, mode, run_dir, cfg)?;
    obs.trust(&pair);
    let ready = match handshake(&obs, &mut feed, &mut pair, study) {
        Ok(r) => r,
        Err(e) => {
            // A child that died during set-up leaves a half-created node: remove it now.
            drop(pair);
            drop(feed);
            drop(obs);
            let removed = ipc::remove_dead_nodes();
            return Err(if removed.is_empty() {
                e
            } else {
                anyhow!(
                    "{e:#}; removed the iceoryx2 resources of the {} dead node(s) it left",
                    removed.len()
                )
            });
        }
    };
    if !ready {
        return stopped_before_start(&obs, pair, law, study, rid, keep);
    }

    let mut sched_warnings = rt::apply(&rt::Sched {
        core: Layout::cpu(layout.supervisor_cpu),
        fifo_priority: 0,
        lock_memory: false,
    });
    if mode == LoopMode::Realtime {
        sched_warnings.extend(fifo_share_warnings(
            layout,
            cfg.loop_.ts_s,
            rt::rt_share_limit(),
        ));
    }
    let n = study.reference.n as u64;
    let ts_ns = (cfg.loop_.ts_s * 1e9).round() as u64;
    // Allocate (and touch) everything the observer fills before START, not after: the loop does
    // not wait for the supervisor (regression: a 10-minute lockstep run lost its first 32 k
    // ticks while the supervisor allocated per-tick tables after START).
    let mut streams = Observation::new(
        lawrun::recorder(study, law, keep)?,
        TimingAcc::new(n, ts_ns, mode == LoopMode::Realtime)
            .with_hlogs(run_dir, &format!("{law}.")),
        cfg.record
            .timing_csv
            .then(|| TimingCsv::create(&run_dir.join(format!("{law}.timing.csv"))))
            .transpose()?,
    );
    let mut start = ControlMsg::new(ControlKind::Start, Sender::Supervisor);
    start.ticks = n;
    start.q0 = study.reference.q0().into();
    // Both children poll for START every ≤ 1 ms: tick 0 comes 10 ms after it.
    start.t0_ns = rt::now_ns() + 10_000_000;
    let steal_before = crate::timing::steal_jiffies();
    obs.control.send_copy(start).ipc("send START")?;

    let ending = observe(&obs, &mut feed, &mut pair, study, &mut streams)?;
    let mut child_messages = pair.logs.messages();
    child_messages.extend(
        obs.intrusions()
            .into_iter()
            .map(|i| format!("deltaloop: {i}")),
    );
    let cause = if ending.interrupted || ending.diverged_stop {
        None
    } else {
        fault_cause(&ending, &pair, &streams)
    };
    let (plant_rss, ctrl_rss) = (pair.plant.peak_rss_kib, pair.controller.peak_rss_kib);
    drop(pair);
    // A child killed by a signal leaves its iceoryx2 node behind: the surviving supervisor
    // removes it now (and says so) rather than leaving it to the next run.
    let removed = ipc::remove_dead_nodes();
    if !removed.is_empty() {
        child_messages.push(format!(
            "removed the iceoryx2 resources of {} dead node(s): {}",
            removed.len(),
            removed.join(", ")
        ));
    }
    child_messages.extend(
        sched_warnings
            .into_iter()
            .map(|w| format!("deltaloop: warning: {w}")),
    );
    let (run, mut timing) = streams.finish(ending.interrupted, cause.as_ref())?;
    timing.steal = crate::timing::steal_ms_between(&steal_before, &crate::timing::steal_jiffies());
    timing.peak_rss = PeakRss::from_kib(own_peak_rss_kib(), plant_rss, ctrl_rss);
    Ok(ProcessRun {
        fault: cause,
        interrupted: ending.interrupted,
        run_id: rid,
        run,
        timing,
        child_messages,
    })
}

/// Warnings for realtime loop processes that poll at SCHED_FIFO for more of each period than the
/// kernel's real-time limit (`limit`, a share of the CPU) allows: the kernel then stops them to
/// run the other tasks waiting on their CPU, and the loop freezes for up to tens of ms (seen: a
/// controller polling from 290 µs before each 300 µs deadline stalled 30 ms and the plant
/// stopped the run). Each process polls at least from its early wake-up to the deadline.
fn fifo_share_warnings(layout: &Layout, ts_s: f64, limit: Option<f64>) -> Vec<String> {
    let Some(limit) = limit else {
        return Vec::new();
    };
    let period_us = ts_s * 1e6;
    [
        (
            "plant",
            "wake_early_us",
            layout.plant_priority,
            layout.plant_cpu,
            layout.wake_early_us.map(f64::from),
        ),
        (
            "controller",
            "controller_wake_early_us",
            layout.controller_priority,
            layout.controller_cpu,
            // −1: the controller blocks on its event and polls nothing early.
            layout
                .controller_wake_early_us
                .filter(|u| *u >= 0)
                .map(f64::from),
        ),
    ]
    .into_iter()
    .filter_map(|(who, field, prio, cpu, us)| {
        let us = us?;
        let share = us / period_us;
        (prio.unwrap_or(0) > 0 && share >= limit).then(|| {
            format!(
                "[loop.realtime] {field} = {us:.0}: the {who} polls at SCHED_FIFO {:.1} % of every {period_us:.0} µs period, above the kernel's real-time limit of {:.1} % (sched_rt_runtime_us); the kernel will stop it for up to tens of ms to run other tasks on CPU {}; keep {field} below {:.0}",
                share * 100.0,
                limit * 100.0,
                Layout::cpu(cpu).map_or("(unpinned)".into(), |c| c.to_string()),
                limit * period_us
            )
        })
    })
    .collect()
}

/// Ctrl-C (or SIGTERM, SIGHUP) during the handshake: no START is sent; STOP releases both
/// children, which exit at once; the run holds no tick.
fn stopped_before_start(
    obs: &Observer,
    mut pair: Pair,
    law: Law,
    study: &Study,
    run_id: String,
    keep: &Keep,
) -> Result<ProcessRun> {
    obs.stop();
    // A child that had not subscribed yet misses STOP: dropping the pair sends it SIGTERM.
    let end = rt::now_ns() + 200_000_000;
    while (pair.plant.exited().is_none() || pair.controller.exited().is_none())
        && rt::now_ns() < end
    {
        std::thread::sleep(Duration::from_millis(2));
    }
    // Read the logs after the children are gone, so their last lines are in.
    let logs = pair.logs.clone();
    drop(pair);
    let child_messages = logs.messages();
    let mut rec = lawrun::recorder(study, law, keep)?;
    rec.interrupt();
    Ok(ProcessRun {
        fault: None,
        interrupted: true,
        run_id,
        run: lawrun::finish(rec, None)?,
        timing: Timing::default(),
        child_messages,
    })
}

/// How a child ended, in words: a signal by its name, and SIGBUS with its likely cause.
fn status_text(s: ExitStatus) -> String {
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

/// The line of a child's log that says why it stopped (see [`peer_text::reason`]).
fn last_line(path: &Path) -> String {
    Tail::read(path).reason()
}

/// One line saying what went wrong, or None when both children finished normally.
/// The tick is the one the plant's FAULT message names, else the tick after its last telemetry.
fn fault_cause(ending: &Ending, pair: &Pair, streams: &Observation<'_>) -> Option<Fault> {
    let (plant, ctrl) = (ending.plant, ending.controller);
    let (plant_log, ctrl_log) = (&pair.logs.plant, &pair.logs.controller);
    let ok = |s: Option<ExitStatus>| s.is_some_and(|s| s.success());
    let (last_torque, last_tel) = (streams.last_torque, streams.last_tel);
    // A plant that exits 0 has finished the run: the final state N + 1 says so. Without it (and
    // without DIVERGED) it quit early (regression: reported as a divergence, or as a fault of the
    // controller that never said the plant had exited).
    let n = streams.window.last - 1;
    let plant_quit = ok(plant) && streams.diverged.is_none() && streams.final_tick != Some(n + 1);
    if ok(plant) && ok(ctrl) && !plant_quit {
        return None;
    }
    let tick = streams
        .plant_fault
        .as_ref()
        .map_or(last_tel.map_or(0, |m| m.tick + 1), |f| f.tick);
    let mut parts = Vec::new();
    if plant_quit {
        parts.push(match last_tel {
            Some(m) => format!(
                "the plant exited (status 0) after tick {} of {n}, before the end of the run",
                m.tick
            ),
            None => format!("the plant exited (status 0) before tick 0 of {n}"),
        });
    }
    // A child still running when the supervisor stopped it is not a cause (status None).
    if ctrl.is_some() && !ok(ctrl) {
        let what = ctrl.map_or("did not exit".into(), status_text);
        let line = last_line(ctrl_log);
        parts.push(if line.is_empty() {
            format!("the controller {what}")
        } else {
            format!("the controller {what} ({line})")
        });
    }
    let line = last_line(plant_log);
    if plant.is_some() && !ok(plant) {
        let what = plant.map_or("did not exit".into(), status_text);
        parts.push(if line.is_empty() {
            format!("the plant {what}")
        } else {
            format!(
                "the plant {what}: {}",
                line.trim_start_matches("deltaloop-plant: ")
            )
        });
    }
    // The plant said why it stopped the loop (FAULT): keep that, even if it could not finish
    // (still braking when it was stopped, or its log says something else last).
    if let Some(f) = &streams.plant_fault
        && !line.contains(&f.cause)
    {
        parts.push(format!(
            "the plant stopped the loop at tick {}: {}",
            f.tick, f.cause
        ));
    }
    // How long after the dead peer's last message the supervisor saw it exit.
    if let Some((noticed, who)) = ending.first_exit {
        let last = if who == Sender::Controller {
            last_torque.map(|t| t.t_publish_ns)
        } else {
            last_tel.map(|m| m.t_wake_ns)
        };
        if let Some(t) = last {
            parts.push(format!(
                "the supervisor saw the {} exit {:.1} ms after its last message",
                role(who),
                noticed.saturating_sub(t) as f64 * 1e-6
            ));
        }
    }
    // The plant's FAULT text is a peer's too: one printable line, bounded.
    let cause = parts.join("; ");
    Some(Fault {
        tick,
        cause: peer_text::sanitize(cause.as_bytes(), 4 * peer_text::MAX_CHARS),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn split_with(controller_early_us: i32) -> Layout {
        Layout {
            controller_wake_early_us: Some(controller_early_us),
            ..Layout::realtime_split_cpus()
        }
    }

    /// Regression: a controller told to wake 290 µs before each 300 µs deadline polled 97 % of
    /// the time at SCHED_FIFO; 22 s in, the kernel stopped it for 30 ms to run the supervisor on
    /// its CPU, and the plant ended the run for a silent controller. Nothing had warned.
    #[test]
    fn regression_a_fifo_poll_above_the_kernels_real_time_limit_is_named_with_its_field() {
        let w = fifo_share_warnings(&split_with(290), 3e-4, Some(0.95));
        assert_eq!(w.len(), 1, "{w:?}");
        assert!(
            w[0].contains("controller_wake_early_us = 290")
                && w[0].contains("96.7 %")
                && w[0].contains("95.0 %")
                && w[0].contains("CPU 0")
                && w[0].contains("below 285"),
            "{}",
            w[0]
        );
    }

    #[test]
    fn the_shipped_layouts_and_unlimited_or_non_fifo_loops_get_no_warning() {
        for layout in [
            Layout::realtime_default(),
            Layout::realtime_split_cpus(),
            Layout::realtime_one_cpu_yield(),
        ] {
            assert!(fifo_share_warnings(&layout, 3e-4, Some(0.95)).is_empty());
        }
        assert!(fifo_share_warnings(&split_with(290), 3e-4, None).is_empty());
        let other = Layout {
            controller_priority: Some(0),
            ..split_with(290)
        };
        assert!(fifo_share_warnings(&other, 3e-4, Some(0.95)).is_empty());
        // The controller blocking on its event (−1) polls nothing early.
        assert!(fifo_share_warnings(&split_with(-1), 3e-4, Some(0.95)).is_empty());
    }

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

    /// A child's control service is believed from the child or a process it started (a wrapper
    /// script's child), never from another branch of the tree.
    #[test]
    fn a_process_belongs_to_its_own_tree_and_its_ancestors_not_to_others() {
        let me = std::process::id();
        // SAFETY: getppid has no preconditions.
        let parent = unsafe { libc::getppid() } as u32;
        assert!(in_process_tree(me, me));
        assert!(in_process_tree(me, parent));
        assert!(!in_process_tree(parent, me));
        assert!(!in_process_tree(1, me));
        assert!(!in_process_tree(u32::MAX, me), "no such process");
    }

    #[test]
    fn the_plant_is_checked_too() {
        let layout = Layout {
            wake_early_us: Some(300),
            ..Layout::realtime_default()
        };
        let w = fifo_share_warnings(&layout, 3e-4, Some(0.95));
        assert_eq!(w.len(), 1, "{w:?}");
        assert!(w[0].contains("wake_early_us = 300") && w[0].contains("the plant"));
    }
}
