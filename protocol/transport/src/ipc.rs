//! iceoryx2 services of one run. Every process opens them through these functions, so the QoS
//! settings agree (iceoryx2 refuses to open a service with different settings). Service and node
//! names carry the run id: two runs, or two tests in parallel, never meet.

pub use crate::iox::{IpcContext, IpcError, Svc, describe_process};
pub use crate::ports::{
    ControlIn, ControlOut, ControlService, Ping, RefChunk, RefIn, RefOut, RunNode, Sent, StateIn,
    StateOut, StateService, TelemetryIn, TelemetryOut, TelemetryService, TorqueIn, TorqueOut,
    TorqueService, Wake,
};
use crate::wire::{self, ControlMsg, RefSample, Sender, StateMsg, TelemetryMsg, TorqueMsg};
/// iceoryx2's names the ports' users see (they need not depend on iceoryx2).
pub use iceoryx2::identifiers::UniquePublisherId;
pub use iceoryx2::node::Node;
use iceoryx2::node::NodeView;
pub use iceoryx2::port::listener::ListenerWaitError;
use iceoryx2::prelude::*;
use iceoryx2::service::builder;
use iceoryx2::service::port_factory::{event, publish_subscribe};
use std::fmt::Debug;

/// Per-subscriber queue of an observer (the supervisor): 2.4 s of ticks at 3.3 kHz.
pub const OBSERVER_BUFFER: usize = 8192;
/// How long each handshake step (READY, ARMED, START) may take before the run is given up, ns.
pub const HANDSHAKE_TIMEOUT_NS: u64 = 30_000_000_000;
/// How long the built-in plant and controller wait for the supervisor's reference and START: the
/// whole handshake of a run across the link, whose near bridge waits up to
/// [`HANDSHAKE_TIMEOUT_NS`] for the far side to join before the far side's own steps begin. ns.
pub const START_TIMEOUT_NS: u64 = 2 * HANDSHAKE_TIMEOUT_NS;
/// Per-subscriber queue of a bridge (`deltaloop-bridge`), which relays every message across the
/// link: as deep as an observer's, so a bridge the host holds up loses nothing (regression: the
/// far side's torque queue held [`LOOP_BUFFER`] replies, a bridge held up for two ticks lost the
/// oldest, and the plant's host recorded as unanswered states the controller had answered, so the
/// run did not replay).
pub const RELAY_BUFFER: usize = OBSERVER_BUFFER;
/// Per-subscriber queue in the loop itself: the loop always takes the newest sample.
pub const LOOP_BUFFER: usize = 4;

/// The iceoryx2 configuration, set in code (defaults), so no process looks for a config file or
/// warns that there is none. iceoryx2's own silent clean-up of dead nodes is off: the supervisor
/// removes them explicitly before a run ([`remove_dead_nodes`]) and reports what it removed.
///
/// iceoryx2's own log is set to errors only (override with `IOX2_LOG_LEVEL`): its warnings, such as
/// "No config file was loaded" when it removes a half-created node, are not the user's business;
/// deltaloop reports what it cleaned itself.
pub fn config() -> Config {
    iceoryx2::prelude::set_log_level_from_env_or(iceoryx2::prelude::LogLevel::Error);
    let mut c = Config::default();
    c.global.node.cleanup_dead_nodes_on_creation = false;
    c.global.node.cleanup_dead_nodes_on_destruction = false;
    c.global.service.cleanup_dead_nodes_on_open = false;
    if let Some((root, prefix)) = own_root() {
        // Checked in own_root: an absolute path of at most 255 bytes, a short file name.
        if let (Ok(r), Ok(p)) = (Path::new(root.as_bytes()), FileName::new(prefix.as_bytes())) {
            c.global.set_root_path(&r);
            c.global.prefix = p;
        }
    }
    c
}

/// The environment variable that gives this process its own iceoryx2 root: a directory (absolute
/// path) for iceoryx2's node and service files, and a shared-memory prefix derived from it, so
/// that processes with different roots never see each other's services on one machine (two
/// "hosts" in network namespaces of one machine, joined only by `deltaloop-bridge`). Unset: the
/// iceoryx2 defaults (`/tmp/iceoryx2/`, prefix `iox2_`).
pub const ROOT_ENV: &str = "DELTALOOP_IOX2_ROOT";

/// The iceoryx2 root directory (ending in `/`) and shared-memory prefix [`ROOT_ENV`] asks for, if
/// it is set to a usable absolute path; the prefix is `iox2_<FNV-1a 32 of the path, hex>_` (the
/// Python helper derives the same).
pub fn own_root() -> Option<(String, String)> {
    let v = std::env::var(ROOT_ENV).ok()?;
    root_of(&v)
}

/// [`own_root`] for the value `v`.
pub fn root_of(v: &str) -> Option<(String, String)> {
    if !v.starts_with('/') || v.len() > 200 || v.contains('\0') {
        return None;
    }
    let root = if v.ends_with('/') {
        v.to_string()
    } else {
        format!("{v}/")
    };
    let mut h: u32 = 0x811c_9dc5;
    for b in root.as_bytes() {
        h = (h ^ u32::from(*b)).wrapping_mul(0x0100_0193);
    }
    Some((root, format!("iox2_{h:08x}_")))
}

/// A node for `role` in run `run_id`. Signal handling stays with the process.
pub fn node(role: &str, run_id: &str) -> Result<RunNode, IpcError> {
    let name = NodeName::new(&format!("deltaloop-{role}-{run_id}")).ipc("node name")?;
    NodeBuilder::new()
        .name(&name)
        .config(&config())
        .signal_handling_mode(SignalHandlingMode::Disabled)
        .create::<Svc>()
        .ipc(format!("create node for {role}"))
        .map(Into::into)
}

/// A run id unique on this machine: pid, a per-process counter and the clock.
pub fn new_run_id() -> String {
    static N: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
    format!(
        "{:x}-{:x}-{:x}",
        std::process::id(),
        N.fetch_add(1, std::sync::atomic::Ordering::Relaxed),
        crate::rt::now_ns() & 0xffff_ffff
    )
}

/// `deltaloop/<run id>/<what>`.
pub fn service_name(run_id: &str, what: &str) -> Result<ServiceName, IpcError> {
    ServiceName::new(&format!("deltaloop/{run_id}/{what}")).ipc(format!("service name {what}"))
}

/// How long a loop process keeps its ports after its last message. A subscriber drops what it
/// has not yet taken from a publisher that is gone, and the supervisor drains every millisecond:
/// without this, a controller released at once by a plant that diverged took its last replies
/// with it, and the run was reported as a fault with its last tick lost.
pub const LINGER: std::time::Duration = std::time::Duration::from_millis(20);

/// Subscriber slots the loop's services (`state`, `torque`, `telemetry`, `control`) keep free
/// beyond the run's own: an external tool can watch a live run without taking a slot the loop
/// needs.
pub const SPARE: usize = 1;

/// Connects these loop ports (publishers, subscribers, notifiers) to every peer port that exists
/// now. iceoryx2 otherwise connects lazily, in the first send, receive or notify that notices a
/// new peer: it maps the peer's data segment there (a few MiB, every page locked under `mlockall`:
/// hundreds of µs) or opens the listener's socket (≈ 100 µs), which made tick 0 miss its budget.
/// Called after START, when every loop port exists.
pub fn connect_now(ports: &[&dyn crate::ports::Connect]) -> Result<(), IpcError> {
    for p in ports {
        p.connect()?;
    }
    Ok(())
}

/// Nodes a service admits: supervisor, plant, controller, and one spare for an observer.
pub const MAX_NODES: usize = 4;

/// Opens (or creates, for the supervisor) a service of this wire version: the creator stores
/// [`wire::WIRE_ATTRIBUTE`] = [`wire::WIRE_VERSION`], an opener requires it, so a peer of another
/// version is refused at set-up with a line that says so.
fn wire_version() -> Result<iceoryx2::service::attribute::AttributeVerifier, IpcError> {
    let key = wire::WIRE_ATTRIBUTE.try_into().ipc("wire attribute key")?;
    let value = wire::WIRE_VERSION
        .to_string()
        .as_str()
        .try_into()
        .ipc("wire attribute value")?;
    iceoryx2::service::attribute::AttributeVerifier::new()
        .require(&key, &value)
        .ipc("wire attribute")
}

/// The error of opening service `what`, with what it means when it is deltaloop's to say.
fn open_error(what: &str, e: impl Debug) -> IpcError {
    let detail = format!("{e:?}");
    let hint = if detail.contains("IncompatibleAttributes") {
        format!(
            " (the run speaks another deltaloop wire version than this process's {}: docs/protocol.md §2)",
            wire::WIRE_VERSION
        )
    } else {
        String::new()
    };
    IpcError {
        what: format!("open service {what}"),
        detail: detail + &hint,
    }
}

/// An `open_or_create` error that says the service is absent, which, right after this process's
/// own create failed, means the peer is half-way through creating it.
trait HalfCreated {
    fn half_created(&self) -> bool;
}

impl HalfCreated for builder::event::EventOpenOrCreateError {
    fn half_created(&self) -> bool {
        matches!(
            self,
            Self::EventOpenError(builder::event::EventOpenError::DoesNotExist)
        )
    }
}

impl HalfCreated for builder::publish_subscribe::PublishSubscribeOpenOrCreateError {
    fn half_created(&self) -> bool {
        matches!(
            self,
            Self::PublishSubscribeOpenError(
                builder::publish_subscribe::PublishSubscribeOpenError::DoesNotExist,
            )
        )
    }
}

/// Opens or creates a service, again while another process is half-way through creating it.
/// iceoryx2's `open_or_create` can find the service absent, fail to create it because the other
/// process just did, and then find it still absent while that one is initialising it
/// ([`HalfCreated`]). Set-up only: at most [`OPEN_RACE_TRIES`] tries, 2 ms apart.
fn open_racing<T, E: HalfCreated>(mut open: impl FnMut() -> Result<T, E>) -> Result<T, E> {
    let mut tries = 1;
    loop {
        match open() {
            Err(e) if tries < OPEN_RACE_TRIES && e.half_created() => {
                tries += 1;
                std::thread::sleep(std::time::Duration::from_millis(2));
            }
            done => return done,
        }
    }
}

/// How often [`open_racing`] tries (100 ms in all).
const OPEN_RACE_TRIES: u32 = 50;

fn pubsub<T: ZeroCopySend + Debug + Copy + 'static>(
    node: &Node<Svc>,
    run_id: &str,
    what: &str,
    publishers: usize,
    subscribers: usize,
    buffer: usize,
) -> Result<publish_subscribe::PortFactory<Svc, T, ()>, IpcError> {
    let (name, version) = (service_name(run_id, what)?, wire_version()?);
    open_racing(|| {
        node.service_builder(&name)
            .publish_subscribe::<T>()
            .max_publishers(publishers)
            .max_subscribers(subscribers)
            .max_nodes(MAX_NODES)
            .subscriber_max_buffer_size(buffer)
            .history_size(0)
            // A slow observer loses its oldest samples (counted by tick gaps); it never blocks
            // the loop.
            .enable_safe_overflow(true)
            .open_or_create_with_attributes(&version)
    })
    .map_err(|e| open_error(what, e))
}

/// Plant → controller + supervisor.
pub fn state(node: &Node<Svc>, run_id: &str) -> Result<StateService, IpcError> {
    pubsub::<StateMsg>(node, run_id, "state", 1, 2 + SPARE, OBSERVER_BUFFER).map(Into::into)
}

/// Controller → plant + supervisor.
pub fn torque(node: &Node<Svc>, run_id: &str) -> Result<TorqueService, IpcError> {
    pubsub::<TorqueMsg>(node, run_id, "torque", 1, 2 + SPARE, OBSERVER_BUFFER).map(Into::into)
}

/// Plant → supervisor.
pub fn telemetry(node: &Node<Svc>, run_id: &str) -> Result<TelemetryService, IpcError> {
    pubsub::<TelemetryMsg>(node, run_id, "telemetry", 1, 1 + SPARE, OBSERVER_BUFFER).map(Into::into)
}

/// The control service `from` publishes on: `control` (the supervisor: START, STOP),
/// `control-plant` (READY, FAULT, DIVERGED, STOPPED), `control-controller` (READY, ARMED).
///
/// One service per sender, each with a single publisher slot, so a message's service says who
/// sent it and no peer can speak for another: the supervisor creates all three, and takes the
/// slot of `control`, before it starts the children; it checks that the slot of each child's
/// service is held by that child's own process (docs/protocol.md §5, §12).
pub fn control_service(from: Sender) -> &'static str {
    match from {
        Sender::Supervisor => "control",
        Sender::Plant => "control-plant",
        Sender::Controller => "control-controller",
    }
}

/// Run control sent by `from` (see [`control_service`]): one publisher, the other two roles and
/// an observer subscribe.
pub fn control(node: &Node<Svc>, run_id: &str, from: Sender) -> Result<ControlService, IpcError> {
    pubsub::<ControlMsg>(node, run_id, control_service(from), 1, 2 + SPARE, 64).map(Into::into)
}

/// A loop process's two ends of run control: its publisher on its own service, its subscriber on
/// the supervisor's.
pub type ControlPorts = (ControlOut, ControlIn);

/// Opens run control for the loop process `me`: a publisher on its own service, a subscriber on
/// the supervisor's. The publisher fails if another process already holds the slot.
pub fn control_ports(node: &Node<Svc>, run_id: &str, me: Sender) -> Result<ControlPorts, IpcError> {
    let publisher = control(node, run_id, me)?.sole_publisher(control_service(me))?;
    let subscriber =
        control(node, run_id, Sender::Supervisor)?.subscriber(None, "control subscriber")?;
    Ok((publisher, subscriber))
}

/// Rows of the joint reference per sample (one chunk): 4096 ticks, 1.2 s at Ts = 0.3 ms, 320 KiB.
///
/// # The reference hand-off
///
/// The supervisor sends the joint reference (total = N + 2 rows, ticks 0..=N + 1) in chunks, so
/// neither shared memory nor the controller grows with the run. With C = `REF_CHUNK`:
///
/// - chunk c holds ticks [c·C, min((c + 1)·C, total)), each row stamped with its
///   [`RefSample::tick`];
/// - the controller keeps a ring of [`REF_RING`]·C rows: the row of tick k sits in slot
///   k mod (`REF_RING`·C) and is valid iff that slot's `tick == k`;
/// - the supervisor sends chunks 0..min(`REF_RING`, chunks) before START, and chunk c ≥ `REF_RING`
///   only once it has seen a torque reply for some tick a with a + 1 ≥ (c − `REF_RING` + 1)·C.
///   Chunk c overwrites chunk c − `REF_RING` in the ring; that reply shows the controller is past
///   the last tick of that chunk, and it never goes back, so the chunk is dead.
///
/// The same reply shows the controller has taken chunks 0..=c − `REF_RING` off its queue (it
/// needed tick a's row, and the queue is in order), so at most `REF_RING` chunks are ever queued:
/// a subscriber buffer of `REF_RING` never overflows and the supervisor never waits. If the
/// supervisor falls behind anyway, the controller waits for the row up to the silence timeout and
/// then ends with a fault that says so.
pub const REF_CHUNK: usize = 4096;
/// Chunks the controller's reference ring holds (and its subscriber queues): 16, so the
/// supervisor may run up to 15 chunks (18 s at Ts = 0.3 ms) ahead of the loop; the ring costs the
/// controller 5 MiB.
pub const REF_RING: usize = 16;

/// Supervisor → controller: the joint reference in chunks of up to [`REF_CHUNK`] rows (the rule is
/// at [`REF_CHUNK`]). One publisher, one subscriber, no history (the subscriber exists before the
/// first chunk is sent: the controller reports READY after opening it). The queue holds
/// [`REF_RING`] chunks, which the rule never exceeds; safe overflow keeps the supervisor from ever
/// blocking should it be exceeded (the controller would then miss a row and say so). The
/// controller copies each chunk into its ring and drops it at once, so it borrows one at a time.
pub fn reference(
    node: &Node<Svc>,
    run_id: &str,
) -> Result<publish_subscribe::PortFactory<Svc, [RefSample], ()>, IpcError> {
    let (name, version) = (service_name(run_id, "reference")?, wire_version()?);
    open_racing(|| {
        node.service_builder(&name)
            .publish_subscribe::<[RefSample]>()
            .max_publishers(1)
            // No spare here: the reference is the controller's input, not the loop's output, and
            // each subscriber slot would cost REF_RING chunks (5 MiB) of shared memory.
            .max_subscribers(1)
            .max_nodes(MAX_NODES)
            .subscriber_max_buffer_size(REF_RING)
            .subscriber_max_borrowed_samples(1)
            .history_size(0)
            .enable_safe_overflow(true)
            .open_or_create_with_attributes(&version)
    })
    .map_err(|e| open_error("reference", e))
}

/// The supervisor's end of the reference: chunks of up to [`REF_CHUNK`] rows, one loaned at a
/// time (it fills and sends each before the next).
pub fn reference_publisher(node: &Node<Svc>, run_id: &str) -> Result<RefOut, IpcError> {
    reference(node, run_id)?
        .publisher_builder()
        .initial_max_slice_len(REF_CHUNK)
        .max_loaned_samples(1)
        .create()
        .ipc("reference publisher")
        .map(Into::into)
}

/// The controller's end of the reference, queueing up to [`REF_RING`] chunks.
pub fn reference_subscriber(node: &Node<Svc>, run_id: &str) -> Result<RefIn, IpcError> {
    reference(node, run_id)?
        .subscriber_builder()
        .buffer_size(REF_RING)
        .create()
        .ipc("reference subscriber")
        .map(Into::into)
}

/// A wake-up event: `state-ready` wakes the controller, `torque-ready` wakes the plant.
pub fn wakeup(
    node: &Node<Svc>,
    run_id: &str,
    what: &str,
) -> Result<event::PortFactory<Svc>, IpcError> {
    let name = service_name(run_id, what)?;
    open_racing(|| {
        node.service_builder(&name)
            .event()
            .max_notifiers(2)
            .max_listeners(2)
            .max_nodes(4)
            .open_or_create()
    })
    .ipc(format!("open event {what}"))
}

/// The listening end of the wake-up event `what` ([`wakeup`]).
pub fn listener(node: &Node<Svc>, run_id: &str, what: &str) -> Result<Wake, IpcError> {
    wakeup(node, run_id, what)?
        .listener_builder()
        .create()
        .ipc(format!("{what} listener"))
        .map(Into::into)
}

/// The notifying end of the wake-up event `what` ([`wakeup`]).
pub fn notifier(node: &Node<Svc>, run_id: &str, what: &str) -> Result<Ping, IpcError> {
    wakeup(node, run_id, what)?
        .notifier_builder()
        .create()
        .ipc(format!("{what} notifier"))
        .map(Into::into)
}

/// The controller's end of the loop: `state` subscriber (`buffer` deep: [`LOOP_BUFFER`], or
/// [`RELAY_BUFFER`] in a bridge), `torque`
/// publisher, `state-ready` listener, `torque-ready` notifier (the built-in controller and the
/// bridge's near side, which stands in for it).
pub type ControllerLoop = (StateIn, TorqueOut, Wake, Ping);

/// Opens [`ControllerLoop`].
pub fn controller_loop(
    node: &Node<Svc>,
    run_id: &str,
    buffer: usize,
) -> Result<ControllerLoop, IpcError> {
    Ok((
        state(node, run_id)?.subscriber(Some(buffer), "state subscriber")?,
        torque(node, run_id)?.sole_publisher("torque")?,
        listener(node, run_id, "state-ready")?,
        notifier(node, run_id, "torque-ready")?,
    ))
}

/// Every port of the controller's side of a run: the loop ([`controller_loop`]), the reference
/// chunks and run control. Held by the bridge's near side, which stands in for the controller (the
/// built-in controller keeps its loop ports apart, for the transport it picks at START).
pub struct ControllerPorts {
    pub state: StateIn,
    pub torque: TorqueOut,
    pub state_ready: Wake,
    pub torque_ready: Ping,
    pub reference: RefIn,
    pub control: ControlPorts,
    _node: RunNode,
}

impl ControllerPorts {
    /// Opens them under the node `controller` of run `run_id`, the state queue `buffer` deep.
    pub fn open(run_id: &str, buffer: usize) -> Result<Self, IpcError> {
        let node = node("controller", run_id)?;
        let (state, torque, state_ready, torque_ready) = controller_loop(&node, run_id, buffer)?;
        Ok(Self {
            state,
            torque,
            state_ready,
            torque_ready,
            reference: reference_subscriber(&node, run_id)?,
            control: control_ports(&node, run_id, Sender::Controller)?,
            _node: node,
        })
    }
}

/// The plant's end of the loop: `state` publisher, `torque` subscriber (`buffer` deep, as in
/// [`controller_loop`]),
/// `state-ready` notifier, `torque-ready` listener (the built-in plant and the bridge's far side,
/// which stands in for it).
pub type PlantLoop = (StateOut, TorqueIn, Ping, Wake);

/// Opens [`PlantLoop`].
pub fn plant_loop(node: &Node<Svc>, run_id: &str, buffer: usize) -> Result<PlantLoop, IpcError> {
    Ok((
        state(node, run_id)?.sole_publisher("state")?,
        torque(node, run_id)?.subscriber(Some(buffer), "torque subscriber")?,
        notifier(node, run_id, "state-ready")?,
        listener(node, run_id, "torque-ready")?,
    ))
}

/// Free space of the shared-memory file system iceoryx2 uses (`/dev/shm`), bytes; None if it
/// cannot be read.
pub fn shm_free_bytes() -> Option<u64> {
    let path = c"/dev/shm";
    // SAFETY: statvfs writes into the struct we own; the path is a valid C string.
    let mut st: libc::statvfs = unsafe { std::mem::zeroed() };
    if unsafe { libc::statvfs(path.as_ptr(), &mut st) } != 0 {
        return None;
    }
    Some(st.f_bavail as u64 * st.f_frsize as u64)
}

/// Shared memory one process run maps, bytes: the same for a run of seconds or of hours, since the
/// reference travels in bounded chunks. Measured on iceoryx2 0.10 by summing the sizes of the
/// `/dev/shm` files that a run creates (what `du --apparent-size /dev/shm` counts during a
/// lockstep run): 17,889 KiB, of which 12,129 KiB are the loop, control and event services (with
/// their spare observer slot) and 5,760 KiB the reference publisher's data segment. That segment holds
/// `REF_RING` queued + 1 borrowed + 1 loaned = 18 chunks of `REF_CHUNK` rows of 80 B (5,760 KiB),
/// so it is computed here from the constants; 10 % is added as a margin (≈ 19.2 MiB in all).
pub const fn shm_needed_bytes() -> u64 {
    const SERVICES: u64 = 12_129 * 1024;
    const REFERENCE: u64 = ((REF_RING + 2) * REF_CHUNK * std::mem::size_of::<RefSample>()) as u64;
    let measured = SERVICES + REFERENCE;
    measured + measured / 10
}

/// Err with one line if `needed` bytes of shared memory are not free (`free`), saying how much
/// there is, how much the run needs and what to do.
pub fn check_shm(needed: u64, free: u64) -> Result<(), String> {
    if needed <= free {
        return Ok(());
    }
    let mb = |b: u64| b as f64 / (1024.0 * 1024.0);
    Err(format!(
        "not enough shared memory for this run: /dev/shm has {:.1} MiB free, the run needs about {:.1} MiB (≈ 19.2 MiB per run, whatever its length); free /dev/shm or enlarge it (Docker: --shm-size; its default 64 MiB fits 3 runs)",
        mb(free),
        mb(needed)
    ))
}

/// The names of the iceoryx2 nodes that are alive on this machine (under this process's root).
pub fn alive_node_names() -> Vec<String> {
    let mut names = Vec::new();
    let _ = Node::<Svc>::list(&config(), |state| {
        if let NodeState::Alive(view) = state
            && let Some(d) = view.details()
        {
            names.push(d.name().to_string());
        }
        CallbackProgression::Continue
    });
    names
}

/// Removes the resources of iceoryx2 nodes whose process died (e.g. a run killed with SIGKILL).
/// Returns the names of the nodes it cleaned.
pub fn remove_dead_nodes() -> Vec<String> {
    remove_dead_nodes_where(&|_| true)
}

/// [`remove_dead_nodes`], only for the dead nodes whose name `pick` accepts (e.g. a killed
/// observer of one run, whose subscriber slots stay taken until its node is removed). `pick` is
/// a trait object, not a generic: node listing and clean-up read iceoryx2's TOML files, code
/// every caller would otherwise compile again.
pub fn remove_dead_nodes_where(pick: &dyn Fn(&str) -> bool) -> Vec<String> {
    let mut removed = Vec::new();
    let _ = Node::<Svc>::list(&config(), |state| {
        if let NodeState::Dead(view) = state {
            let name = view
                .details()
                .as_ref()
                .map(|d| d.name().to_string())
                .unwrap_or_else(|| "unnamed".into());
            if pick(&name)
                && view
                    .blocking_remove_stale_resources(core::time::Duration::from_secs(1))
                    .is_ok()
            {
                removed.push(name);
            }
        }
        CallbackProgression::Continue
    });
    removed
}

/// After publishing a sample: whether the peer, which declared it polls until
/// `peer_poll_until_ns`, must still be woken (docs/protocol.md §6.1). The fence makes the sample
/// visible to the peer before the clock is read.
#[inline]
pub fn published_needs_notify(peer_poll_until_ns: u64) -> bool {
    std::sync::atomic::fence(std::sync::atomic::Ordering::SeqCst);
    crate::wire::needs_notify(crate::rt::now_ns(), peer_poll_until_ns)
}

/// Waits until a wake-up event is pending, for at most `timeout_ns`, with nanosecond precision.
/// Does not consume it: the caller drains with `listener.try_wait` when it has time (the sample
/// is already published when the event is, so the reader need not drain before reading).
///
/// iceoryx2's own `Listener::timed_wait` uses a socket receive timeout, which the kernel rounds up
/// to whole jiffies (1–4 ms): useless for a 150 µs budget. This polls the listener's file
/// descriptor with `ppoll` (a high-resolution timer) instead. Returns whether an event is pending.
pub fn wait_event(listener: &Wake, timeout_ns: u64) -> Result<bool, IpcError> {
    let fd = listener.fd();
    let mut pfd = libc::pollfd {
        fd,
        events: libc::POLLIN,
        revents: 0,
    };
    let ts = libc::timespec {
        tv_sec: (timeout_ns / 1_000_000_000) as libc::time_t,
        tv_nsec: (timeout_ns % 1_000_000_000) as libc::c_long,
    };
    // SAFETY: one valid pollfd we own, a valid timespec, no signal mask change.
    let r = unsafe { libc::ppoll(&mut pfd, 1, &ts, std::ptr::null()) };
    if r < 0 {
        let e = std::io::Error::last_os_error();
        if e.kind() == std::io::ErrorKind::Interrupted {
            return Ok(false);
        }
        return Err(IpcError {
            what: "wait for event".into(),
            detail: e.to_string(),
        });
    }
    Ok(r > 0)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A stand-in error for [`open_racing`]'s own rule.
    impl HalfCreated for &str {
        fn half_created(&self) -> bool {
            *self == "DoesNotExist"
        }
    }

    #[test]
    fn regression_a_service_half_created_by_the_peer_is_opened_again() {
        // The peer creates the service between our failed create and our open: DoesNotExist.
        let mut calls = 0;
        let r: Result<u32, &str> = open_racing(|| {
            calls += 1;
            if calls < 3 {
                Err("DoesNotExist")
            } else {
                Ok(7)
            }
        });
        assert_eq!((r, calls), (Ok(7), 3));
        // Any other error is reported at once; a service that stays absent, after the last try.
        let mut calls = 0;
        let r: Result<u32, &str> = open_racing(|| {
            calls += 1;
            Err("IncompatibleAttributes")
        });
        assert_eq!((r, calls), (Err("IncompatibleAttributes"), 1));
        let mut calls = 0;
        let r: Result<u32, &str> = open_racing(|| {
            calls += 1;
            Err("DoesNotExist")
        });
        assert_eq!((r, calls), (Err("DoesNotExist"), OPEN_RACE_TRIES));
        // iceoryx2's own errors: only "absent" on opening is the peer's half-made service.
        use builder::event::{EventCreateError, EventOpenError, EventOpenOrCreateError as E};
        assert!(E::EventOpenError(EventOpenError::DoesNotExist).half_created());
        assert!(!E::EventOpenError(EventOpenError::IncompatibleAttributes).half_created());
        assert!(!E::EventCreateError(EventCreateError::AlreadyExists).half_created());
        use builder::publish_subscribe::{
            PublishSubscribeOpenError as O, PublishSubscribeOpenOrCreateError as P,
        };
        assert!(P::PublishSubscribeOpenError(O::DoesNotExist).half_created());
        assert!(!P::PublishSubscribeOpenError(O::IncompatibleAttributes).half_created());
    }
}
