//! The children of a process run and the supervisor's hold on them: spawning the pair (their
//! commands and logs, each child reaped with its resource usage and killed on drop, the
//! process-tree check the control services rely on), the supervisor's ports (the children's
//! control services, the observers of the loop streams) and the handshake: READY from both, the
//! first reference chunks, ARMED, START; or STOP when a signal comes first.

use super::status::status_text;
use super::{ProcessRun, Started, exe_dir, new_run_id, role};
use crate::feed::ReferenceFeed;
use crate::lawrun::{self, Keep};
use crate::peer_text::{self, Tail};
use anyhow::{Context, Result, anyhow, bail};
use deltaloop_config::{Law, LoopMode, RemoteSide, RunConfig};
use deltaloop_study::Study;
use deltaloop_timing::Timing;
use deltaloop_transport::ipc::{self, IpcContext, OBSERVER_BUFFER, Svc};
use deltaloop_transport::rt;
use deltaloop_transport::wire::{
    ControlKind, ControlMsg, Sender, StateMsg, TelemetryMsg, TorqueMsg,
};
use std::cell::Cell;
use std::ops::ControlFlow;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Stdio};
use std::time::Duration;

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

fn spawn(
    launch: &Launch,
    args: &[String],
    log: &Path,
    who: Sender,
    handoff: Option<&deltaloop_transport::handoff::End>,
) -> Result<Reaped> {
    let err =
        std::fs::File::create(log).with_context(|| format!("cannot create {}", log.display()))?;
    let mut cmd = Command::new(&launch.program);
    // A near bridge (a remote run) gets the link key; no other child ever does.
    crate::link_key::hand_key(
        &mut cmd,
        &launch.program,
        launch.args.first().map(String::as_str),
    );
    cmd.args(&launch.args)
        .args(args)
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(err);
    // Stopped in order by the supervisor, and by the kernel if the supervisor is killed
    // outright (regression: a SIGKILLed supervisor left its plant running, a soak's up to 24 h).
    deltaloop_transport::rt::die_with_parent(&mut cmd);
    // Across two hosts: the near bridge and the loop process beside it share a private socket
    // pair, over which the bridge may hand the link's socket on at START (the direct path).
    if let Some(end) = handoff {
        deltaloop_transport::handoff::inherit(&mut cmd, end);
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

/// The two children of one run and their stderr logs.
pub(super) struct Pair {
    plant: Reaped,
    controller: Reaped,
    logs: Logs,
    /// The plant's and the controller's command lines, for messages.
    shown: (String, String),
    /// Where a near bridge (one side across the link) writes the link's report: present once a
    /// far side joined. None when both children are on this host.
    link_report: Option<PathBuf>,
    /// What the controller called itself in its READY (its text; escaped, bounded), if anything.
    controller_label: Option<String>,
}

/// The children's stderr logs.
#[derive(Clone)]
struct Logs {
    plant: PathBuf,
    controller: PathBuf,
}

impl Logs {
    /// The plant's log and the controller's.
    fn paths(&self) -> (&Path, &Path) {
        (&self.plant, &self.controller)
    }

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
                (!r.is_empty())
                    .then(|| format!("the {who}: {r} (log: {}){}", p.display(), slot_hint(&r)))
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
        // One end for the near bridge (in the remote process's place), one for the process here.
        let pair = match &cfg.link {
            Some(_) => Some(deltaloop_transport::handoff::pair().context("a socket pair")?),
            None => None,
        };
        let (for_plant, for_controller) = match (&cfg.link, &pair) {
            (Some(l), Some((bridge, local))) if l.remote == RemoteSide::Controller => {
                (Some(local), Some(bridge))
            }
            (Some(_), Some((bridge, local))) => (Some(bridge), Some(local)),
            _ => (None, None),
        };
        let plant = spawn(&pl, &common, &plant_log, Sender::Plant, for_plant)?;
        let mut ctrl_args = common;
        ctrl_args.extend(["--law".to_string(), law.name().to_string()]);
        let controller = spawn(
            &cl,
            &ctrl_args,
            &ctrl_log,
            Sender::Controller,
            for_controller,
        )?;
        drop(pair);
        Ok(Self {
            plant,
            controller,
            logs: Logs {
                plant: plant_log,
                controller: ctrl_log,
            },
            shown: (pl.shown(), cl.shown()),
            link_report: cfg.link.is_some().then(|| {
                deltaloop_link_setup::LinkReport::path(&run_dir.join("config.toml"), run_id)
            }),
            controller_label: None,
        })
    }

    /// Each child's exit status, the plant's first, for those that have exited (reaped then).
    pub(super) fn exited(&mut self) -> (Option<ExitStatus>, Option<ExitStatus>) {
        (self.plant.exited(), self.controller.exited())
    }

    /// Each child's pid while it has not been reaped, the plant's first.
    pub(super) fn pids(&self) -> (Option<u32>, Option<u32>) {
        let pid = |r: &Reaped| r.child.as_ref().map(Child::id);
        (pid(&self.plant), pid(&self.controller))
    }

    /// The last lines both children printed (see [`Logs::messages`]).
    pub(super) fn messages(&self) -> Vec<String> {
        self.logs.messages()
    }

    /// The plant's stderr log and the controller's.
    pub(super) fn log_paths(&self) -> (&Path, &Path) {
        self.logs.paths()
    }

    /// The plant's and the controller's command lines, for messages.
    fn shown(&self) -> &(String, String) {
        &self.shown
    }

    /// Keeps what the controller called itself in its READY.
    fn said_label(&mut self, label: Option<String>) {
        self.controller_label = label;
    }

    /// Ends the pair: each child's peak resident set size, KiB, for those that have exited (the
    /// plant's first), and what the controller called itself; then a child still running is
    /// stopped (see [`Reaped`]).
    pub(super) fn close(mut self) -> ((Option<u64>, Option<u64>), Option<String>) {
        let rss = (self.plant.peak_rss_kib, self.controller.peak_rss_kib);
        (rss, self.controller_label.take())
    }

    /// How long the handshake may take: a run across the link waits for the far side to join
    /// (the near bridge's own deadline, whose message is the more precise one) and then for it.
    fn handshake_timeout_ns(&self) -> u64 {
        if self.link_report.is_some() {
            ipc::START_TIMEOUT_NS
        } else {
            ipc::HANDSHAKE_TIMEOUT_NS
        }
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

    /// For a run across the link, who had joined when a step timed out.
    fn far_side_note(&self) -> String {
        far_side_note(self.link_report.as_deref())
    }
}

/// What a peer's iceoryx2 error about publisher slots means here: the control services are one
/// per sender (wire version 3), so a peer written for one shared `control` cannot open it.
fn slot_hint(reason: &str) -> String {
    if [
        "DoesNotSupportRequestedAmountOfPublishers",
        "ExceedsMaxSupportedPublishers",
    ]
    .iter()
    .any(|e| reason.contains(e))
    {
        format!(
            " — this run speaks deltaloop wire version {}: its control services are one per sender, each with one publisher (the plant publishes on `control-plant`, the controller on `control-controller`, both read `control`); a peer written for one shared `control` service must be updated (docs/protocol.md §2, §3)",
            deltaloop_transport::wire::WIRE_VERSION
        )
    } else {
        String::new()
    }
}

/// Who had joined across the link, from the near bridge's report at `link_report` (empty when the
/// run is not across a link).
fn far_side_note(link_report: Option<&Path>) -> String {
    let Some(path) = link_report else {
        return String::new();
    };
    match deltaloop_link_setup::LinkReport::read(path) {
        Some(r) => format!(
            " (the far side {} had joined, link key {}: see its host's `join` output)",
            r.peer, r.key_fingerprint
        ),
        None => " (no far side had joined)".into(),
    }
}

/// What one child says, on its own control service, believed only from that child: the first
/// publisher seen there must belong to the child's process (or a descendant of it), and after it
/// only that publisher is heard. The service has one publisher slot, so once the child holds it
/// no other process can publish there; if another process took it first, the run is refused.
struct ControlIn {
    sub: ipc::ControlIn,
    who: Sender,
    /// The child's pid, once it is spawned.
    root: Cell<Option<u32>>,
    /// The child's publisher, once its first message proved it.
    publisher: Cell<Option<ipc::UniquePublisherId>>,
    /// The first process not the child's that published here (pid; 0 if its pid is unknown).
    intruder: Cell<Option<u32>>,
}

impl ControlIn {
    fn open(node: &ipc::Node<Svc>, run_id: &str, who: Sender) -> Result<Self> {
        Ok(Self {
            sub: ipc::control(node, run_id, who)?.subscriber(
                None,
                &format!("subscriber on {}", ipc::control_service(who)),
            )?,
            who,
            root: Cell::new(None),
            publisher: Cell::new(None),
            intruder: Cell::new(None),
        })
    }

    /// The kinds `who` may send.
    fn allowed(&self, kind: ControlKind) -> bool {
        match self.who {
            Sender::Plant => kind.said_by_plant(),
            Sender::Controller => kind.said_by_controller(),
            Sender::Supervisor => false,
        }
    }

    /// The next message the child itself sent, of a kind it may send; everything else is dropped
    /// (and a foreign publisher remembered).
    fn receive(&self) -> Result<Option<ControlMsg>> {
        while let Some(sample) = self.sub.receive_sent().ipc("receive control")? {
            let origin = sample.origin;
            let trusted = match (self.publisher.get(), self.root.get()) {
                (Some(id), _) => id == origin,
                (None, Some(root)) => {
                    let pid = sample.pid;
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
            let m = sample.msg;
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
        Some(format!(
            "a process that is not the {who} ({}) published on the {who}'s control service `{}`; its messages were ignored: only the {who} may speak there",
            ipc::describe_process(pid),
            ipc::control_service(self.who),
        ))
    }
}

/// The supervisor's ports: observers of the three loop streams, run control (the reference
/// publisher is a [`ReferenceFeed`] on the same node).
pub(super) struct Observer {
    state: ipc::StateIn,
    torque: ipc::TorqueIn,
    telemetry: ipc::TelemetryIn,
    /// START and STOP: the only publisher of `control`, taken before the children start.
    control: ipc::ControlOut,
    from_plant: ControlIn,
    from_controller: ControlIn,
    node: ipc::RunNode,
}

/// A message the supervisor's ports took: of the loop's streams, or of a child's control service
/// (from that child only).
pub(super) enum Observed {
    State(StateMsg),
    Torque(TorqueMsg),
    Telemetry(TelemetryMsg),
    Plant(ControlMsg),
    Controller(ControlMsg),
}

impl Observer {
    fn open(run_id: &str) -> Result<Self> {
        let node = ipc::node("supervisor", run_id)?;
        Ok(Self {
            state: ipc::state(&node, run_id)?
                .subscriber(Some(OBSERVER_BUFFER), "state observer")?,
            torque: ipc::torque(&node, run_id)?
                .subscriber(Some(OBSERVER_BUFFER), "torque observer")?,
            telemetry: ipc::telemetry(&node, run_id)?
                .subscriber(Some(OBSERVER_BUFFER), "telemetry observer")?,
            control: ipc::control(&node, run_id, Sender::Supervisor)?
                .publisher("control publisher")?,
            from_plant: ControlIn::open(&node, run_id, Sender::Plant)?,
            from_controller: ControlIn::open(&node, run_id, Sender::Controller)?,
            node,
        })
    }

    /// The children's pids: from now on their control services are believed only from them.
    fn trust(&self, pair: &Pair) {
        let (plant, controller) = pair.pids();
        self.from_plant.root.set(plant);
        self.from_controller.root.set(controller);
    }

    /// Hands `on` every message waiting on the ports, in this order: the states, the replies,
    /// the telemetry, then the plant's and the controller's control messages.
    pub(super) fn drain(&self, on: &mut dyn FnMut(Observed) -> Result<()>) -> Result<()> {
        while let Some(s) = self.state.receive().ipc("observe state")? {
            on(Observed::State(s))?;
        }
        while let Some(s) = self.torque.receive().ipc("observe torque")? {
            on(Observed::Torque(s))?;
        }
        while let Some(s) = self.telemetry.receive().ipc("observe telemetry")? {
            on(Observed::Telemetry(s))?;
        }
        while let Some(m) = self.from_plant.receive()? {
            on(Observed::Plant(m))?;
        }
        while let Some(m) = self.from_controller.receive()? {
            on(Observed::Controller(m))?;
        }
        Ok(())
    }

    /// Sends START to both children.
    pub(super) fn start(&self, start: ControlMsg) -> Result<()> {
        self.control.send_copy(start).ipc("send START")?;
        Ok(())
    }

    /// The next message of either child (the plant's first).
    fn receive(&self) -> Result<Option<ControlMsg>> {
        match self.from_plant.receive()? {
            Some(m) => Ok(Some(m)),
            None => self.from_controller.receive(),
        }
    }

    /// Lines about processes that published on a child's control service.
    pub(super) fn intrusions(&self) -> Vec<String> {
        [&self.from_plant, &self.from_controller]
            .iter()
            .filter_map(|c| c.intrusion())
            .collect()
    }

    /// Sends STOP to both children.
    pub(super) fn stop(&self) {
        let _ = self
            .control
            .send_copy(ControlMsg::new(ControlKind::Stop, Sender::Supervisor));
    }
}

/// Opens the supervisor's ports and the reference feed, spawns the pair and runs the handshake.
/// Breaks with the run's result when Ctrl-C (or SIGTERM, SIGHUP) came first: nothing was
/// started (see [`stopped_before_start`]).
pub(super) fn start_pair(
    study: &Study,
    law: Law,
    mode: LoopMode,
    run_dir: &Path,
    keep: &Keep,
) -> Result<ControlFlow<ProcessRun, Started>> {
    // A full /dev/shm would kill a child with SIGBUS mid-set-up: say so up front instead.
    if let Some(free) = ipc::shm_free_bytes() {
        ipc::check_shm(ipc::shm_needed_bytes(), free).map_err(|e| anyhow!(e))?;
    }
    let rid = new_run_id();
    let obs = Observer::open(&rid)?;
    let lead = match mode {
        LoopMode::Lockstep => crate::feed::LOCKSTEP_LEAD_CHUNKS,
        _ => ipc::REF_RING as u64,
    };
    let mut feed = ReferenceFeed::create(
        &obs.node,
        &rid,
        study.reference.row_count(),
        lead,
        study.config.reference_lookahead_ticks(),
    )?;
    let mut pair = Pair::spawn(&rid, law, mode, run_dir, &study.config)?;
    obs.trust(&pair);
    match handshake(&obs, &mut feed, &mut pair, study) {
        Ok(true) => Ok(ControlFlow::Continue(Started {
            rid,
            obs,
            feed,
            pair,
        })),
        Ok(false) => {
            stopped_before_start(&obs, pair, law, study, rid, keep).map(ControlFlow::Break)
        }
        Err(e) => {
            // A child that died during set-up leaves a half-created node: remove it now.
            drop(pair);
            drop(feed);
            drop(obs);
            let removed = ipc::remove_dead_nodes();
            Err(if removed.is_empty() {
                e
            } else {
                anyhow!(
                    "{e:#}; removed the iceoryx2 resources of the {} dead node(s) it left",
                    removed.len()
                )
            })
        }
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
    let timeout = pair.handshake_timeout_ns();
    let deadline = rt::now_ns() + timeout;
    loop {
        while let Some(m) = obs.receive()? {
            if done(&m) {
                return Ok(true);
            }
        }
        if let Some(i) = obs.intrusions().into_iter().next() {
            bail!("{i}");
        }
        if crate::signals::interrupted() {
            return Ok(false);
        }
        pair.check_alive()?;
        if rt::now_ns() > deadline {
            let said = pair.logs.said();
            bail!(
                "{}{} within {} s{}{said}",
                step(),
                pair.far_side_note(),
                timeout / 1_000_000_000,
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
    let pair_shown = pair.shown().clone();
    let ready_from = [std::cell::Cell::new(false), std::cell::Cell::new(false)];
    let mut label = None;
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
            (Some(ControlKind::Ready), Some(Sender::Controller)) => {
                ready_from[1].set(true);
                // A controller may name itself in its READY (the C ABI's dl_run_set_label).
                let t = m.text();
                label =
                    (!t.is_empty()).then(|| crate::peer_text::sanitize(t.as_bytes(), LABEL_CHARS));
            }
            _ => {}
        }
        ready_from.iter().all(std::cell::Cell::get)
    })?;
    if !ready {
        return Ok(false);
    }
    pair.said_label(label);
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

/// The longest name a controller gives itself that the run shows, characters.
const LABEL_CHARS: usize = 64;

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
    while matches!(pair.exited(), (None, _) | (_, None)) && rt::now_ns() < end {
        std::thread::sleep(Duration::from_millis(2));
    }
    // Read the logs after the children are gone, so their last lines are in.
    let logs = pair.logs.clone();
    let (_, controller_label) = pair.close();
    let child_messages = logs.messages();
    let mut rec = lawrun::recorder(study, law, keep)?;
    rec.interrupt();
    Ok(ProcessRun {
        controller_label,
        fault: None,
        interrupted: true,
        run_id,
        run: lawrun::finish(rec, None)?,
        timing: Timing::default(),
        child_messages,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Regression: "never said READY within 30 s" when a far side had joined across the link
    /// and then said nothing: the message now names it (and says so when none had joined).
    #[test]
    fn regression_a_far_side_that_joined_and_fell_silent_is_named() {
        let tmp = tempfile::tempdir().unwrap();
        let path = deltaloop_link_setup::LinkReport::path(&tmp.path().join("config.toml"), "r1");
        assert_eq!(far_side_note(None), "");
        assert_eq!(far_side_note(Some(&path)), " (no far side had joined)");
        let r = deltaloop_link_setup::LinkReport {
            peer: "10.0.0.2:40512".into(),
            key_fingerprint: "ab12cd34".into(),
            ..Default::default()
        };
        r.write(&path).unwrap();
        let note = far_side_note(Some(&path));
        assert!(
            note.contains("far side 10.0.0.2:40512 had joined") && note.contains("ab12cd34"),
            "{note}"
        );
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
}
