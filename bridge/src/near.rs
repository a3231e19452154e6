//! The near side (`deltaloop-bridge near`): started by the supervisor in place of the controller
//! (`deltaloop run --controller-remote`, `--role controller`) or of the plant (`--plant-remote`,
//! `--role plant`), it opens that process's ports on this host, waits for the far side
//! (`deltaloop join`) to connect, and carries the run across: the loop's states and replies as UDP
//! datagrams, run control, the final state and the far process's log and exit over TCP (with a
//! remote controller also the reference chunks, with a remote plant also its telemetry and its
//! control messages). To the supervisor it is the process it replaces: it says what the far one
//! says, publishes what the far one publishes, and exits as the far one exited.
//!
//! Clocks: the plant's host judges every time. With the controller remote this host is the
//! plant's: a reply is republished with `t_publish_ns` = when it reached this host and
//! `t_state_rx_ns` = that time less the far side's residence ([`crate::sides::PlantHost`]). With
//! the plant remote the far side does the same on the plant's host, and this side moves the
//! states' stamps onto this host's clock (their publication = their arrival here) for the
//! supervisor and the controller here (docs/protocol.md §14).
//!
//! Its parts: the listener (`listen`: the wait, the HELLO, the UDP socket), handshake
//! admission (`admit`: who may try the link key, and in what room), run control across the
//! link (`control`), and the two stand-ins (`controller`, `plant`).

use crate::bytes::{self, bytes_of, bytes_of_slice};
use crate::cli::NearArgs as Args;
use crate::emulation::Emulation;
use crate::frame::Kind;
use crate::hello::Hello;
use crate::link::{self, Tcp, Udp};
use crate::seal::{self, End, LinkKey, LinkReport, RefusedCounts, Session, SideRefusals};
use crate::sides::{ControllerHost, PlantHost};
use anyhow::{Context, Result, bail};
use deltaloop_config::RemoteSide;
use deltaloop_config::{LinkPath, LoopMode, RunConfig};
use deltaloop_transport::exit::{EXIT_FAULT, EXIT_STOPPED};
use deltaloop_transport::ipc::{self, ControlPorts, IpcContext};
use deltaloop_transport::rt;
use deltaloop_transport::wire::{self, ControlKind, ControlMsg, Sender, StateMsg, TelemetryMsg};
use std::collections::VecDeque;
use std::net::{SocketAddr, TcpListener, UdpSocket};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

mod admit;
mod control;
mod controller;
mod listen;
mod plant;

use admit::Listen;
pub use control::DIRECT_TURN_NS;
use control::FAR_END_WAIT_NS;
use controller::Near;
use listen::connect;

/// How the far side ended: its exit code and last line.
struct FarEnd {
    code: u8,
    line: String,
}

impl FarEnd {
    /// From an EXIT frame (its payload is at least 4 bytes: checked by the frame's parse).
    fn of(p: &[u8]) -> Self {
        let (code, line) = p.split_at(4);
        let code = u32::from_ne_bytes([code[0], code[1], code[2], code[3]]);
        FarEnd {
            code: u8::try_from(code).unwrap_or(EXIT_FAULT),
            line: wire::escape_peer_text(&String::from_utf8_lossy(line)),
        }
    }

    /// What the near side exits with.
    fn exit(self) -> (u8, Option<String>) {
        let line = (!self.line.is_empty()).then_some(self.line);
        (
            self.code,
            line.or(Some(format!("far side exited {}", self.code))),
        )
    }
}

/// The controller's side of the run on this host, which this bridge holds in its place.
type Ports = ipc::ControllerPorts;

/// The plant's side of the run on this host (`--role plant`), which this bridge holds in its
/// place: the plant's loop ports, its telemetry and control, and the controller's control (its
/// READY and ARMED go to the far side, which says them to the plant there).
struct PlantPorts {
    state: ipc::StateOut,
    torque: ipc::TorqueIn,
    state_ready: ipc::Ping,
    torque_ready: ipc::Wake,
    telemetry: ipc::TelemetryOut,
    control: ControlPorts,
    from_controller: ipc::ControlIn,
    _node: ipc::RunNode,
}

impl PlantPorts {
    fn open(run_id: &str) -> Result<Self> {
        let node = ipc::node("plant", run_id)?;
        let (state, torque, state_ready, torque_ready) =
            ipc::plant_loop(&node, run_id, ipc::RELAY_BUFFER)?;
        Ok(Self {
            state,
            torque,
            state_ready,
            torque_ready,
            telemetry: ipc::telemetry(&node, run_id)?.publisher("telemetry publisher")?,
            control: ipc::control_ports(&node, run_id, Sender::Plant)?,
            from_controller: ipc::control(&node, run_id, Sender::Controller)?
                .subscriber(None, "control-controller subscriber")?,
            _node: node,
        })
    }
}

/// Runs the near side; returns the exit code and its one line (None: completed).
pub fn run(a: &Args, term: &AtomicBool) -> Result<(u8, Option<String>)> {
    // The hand-off to the loop process beside this side, before anything reads the environment.
    let handoff = deltaloop_transport::handoff::End::inherited();
    let cfg = RunConfig::from_file(&a.run.config)?;
    let Some(link) = &cfg.link else {
        bail!(
            "the run's config {} has no [link]: the near bridge stands in for a process on another host (`deltaloop run --controller-remote` or `--plant-remote`)",
            a.run.config.display()
        );
    };
    let at = Listen {
        addr: link
            .listen
            .parse()
            .with_context(|| format!("link.listen {}", link.listen))?,
        role: link.remote,
    };
    let plant = at.role == RemoteSide::Plant;
    let law = match (plant, a.law) {
        (false, None) => bail!("--law is needed with --role controller"),
        (false, l) => l,
        // The plant takes no law.
        (true, _) => None,
    };
    let config = std::fs::read_to_string(&a.run.config)
        .with_context(|| format!("cannot read --config {}", a.run.config.display()))?;
    let run_id = &a.run.run_id;
    let emu = Emulation::of(link);
    let spin_ns = crate::spin_ns_of(&cfg, a.run.mode, link.spin_us)?;
    let hello = Hello {
        run_id: run_id.clone(),
        role: at.role,
        mode: a.run.mode,
        law,
        emulation: emu,
        config,
    };
    let lockstep = a.run.mode == LoopMode::Lockstep;
    let report = LinkReport::path(&a.run.config, run_id);
    if plant {
        let silence_ms = u64::from(cfg.loop_.silence_timeout_ms);
        let ports = PlantPorts::open(run_id)?;
        let Some(mut peer) = connect(&at, &hello, &ports.control, term, &report)? else {
            return Ok(stopped_early());
        };
        (peer.handoff, peer.relay) = (handoff, link.path == LinkPath::Relay);
        peer.loop_cpu = a.run.mode.layout(&cfg).and_then(|l| l.controller_cpu);
        let hold_ns = emu.delay_ns + emu.jitter_ns + 1_000_000;
        plant::stand_in(
            (ports, peer),
            (spin_ns, silence_ms, hold_ns),
            term,
            |peer, r| finish(peer, &report, &emu, None, r),
        )
    } else {
        let ports = Ports::open(run_id, ipc::RELAY_BUFFER)?;
        let Some(mut peer) = connect(&at, &hello, &ports.control, term, &report)? else {
            return Ok(stopped_early());
        };
        (peer.handoff, peer.relay) = (handoff, link.path == LinkPath::Relay);
        peer.loop_cpu = a.run.mode.layout(&cfg).and_then(|l| l.plant_cpu);
        let mut n = Near {
            ports,
            peer,
            host: PlantHost::new(spin_ns, lockstep).with_recall(),
            late_copies: 0,
        };
        let r = n.forward(term);
        if let Some(line) = late_copies_warning(n.late_copies) {
            eprintln!("{line}");
        }
        let counts = n.host.counts();
        finish(&mut n.peer, &report, &emu, Some(counts), r)
    }
}

fn stopped_early() -> (u8, Option<String>) {
    (
        EXIT_STOPPED,
        Some("stopped before the far side joined".into()),
    )
}

/// The link to the far side, and how its run control and end are followed.
struct Peer {
    udp: Udp,
    tcp: Tcp,
    /// What the supervisor is told of the link (written at the end).
    report: LinkReport,
    /// The far process's stderr lines, written to this side's log up to a cap.
    log: FarLog,
    far_end: Option<FarEnd>,
    /// When a STOP (SIGTERM) went to the far side.
    stop_sent_ns: Option<u64>,
    /// The run's session (what the loop process beside this side gets of it: its datagrams'
    /// two keys, [`crate::direct::Offer`]).
    session: Session,
    /// The hand-off to the loop process beside this side, if the supervisor gave one.
    handoff: Option<deltaloop_transport::handoff::End>,
    /// The run asks for the relay (`[link] path = "relay"`).
    relay: bool,
    /// The loop process beside this side took the link's socket at START: this side relays no
    /// datagram and never reads the socket again.
    direct: bool,
    /// The process on the other host.
    role: RemoteSide,
    /// The CPU of the loop process beside this side (from the run's layout), which this side
    /// leaves on the direct path ([`crate::keep_off`]).
    loop_cpu: Option<usize>,
}

/// The far process's stderr lines kept in this side's log at most, bytes: enough for any honest
/// run's messages; a flood is cut (regression: a far side grew `<law>.controller.log` to 97 MB in
/// 0.8 s).
const FAR_LOG_CAP: usize = 1 << 20;

/// The far process's stderr, line by line, escaped, up to [`FAR_LOG_CAP`] bytes.
#[derive(Default)]
struct FarLog {
    written: usize,
    cut: bool,
}

impl FarLog {
    fn line(&mut self, b: &[u8]) {
        if let Some(l) = self.admit(b) {
            eprintln!("{l}");
        }
    }

    /// What to write of the far side's line `b`: the line escaped while under the cap, the
    /// notice of the cut once, then nothing (its exit line still crosses in the EXIT frame).
    fn admit(&mut self, b: &[u8]) -> Option<String> {
        if self.cut {
            return None;
        }
        if self.written + b.len() > FAR_LOG_CAP {
            self.cut = true;
            return Some(format!(
                "deltaloop-bridge: the far side's log passed {} KiB: the rest of it is dropped here",
                FAR_LOG_CAP / 1024
            ));
        }
        self.written += b.len() + 1;
        Some(wire::escape_peer_text(&String::from_utf8_lossy(b)))
    }
}

/// After the loop: the control plane flushed, the ports kept a moment (the supervisor drains
/// them), the link's statistics said (states sent again, replies recovered).
fn finish(
    p: &mut Peer,
    report: &std::path::Path,
    emu: &Emulation,
    counts: Option<crate::sides::PlantHostCounts>,
    r: Result<(u8, Option<String>)>,
) -> Result<(u8, Option<String>)> {
    p.tcp.flush().ok();
    std::thread::sleep(ipc::LINGER);
    take_process_counts(p);
    let near = RefusedCounts::from(p.udp.refused);
    p.report.near = SideRefusals {
        refused_datagrams: near,
        icmp_errors: p.udp.icmp_errors,
    };
    let far_side = p.report.far.unwrap_or_default();
    let far = far_side.refused_datagrams;
    p.report.refused_datagrams = near.plus(far);
    p.report.icmp_errors = p.udp.icmp_errors.saturating_add(far_side.icmp_errors);
    if let Err(e) = p.report.write(report) {
        eprintln!("deltaloop-bridge: warning: {e}");
    }
    let end = r?;
    link_summary(emu, p.udp.emulated_lost, counts);
    if let Some(line) = refused_warning(&p.udp) {
        eprintln!("{line}");
    }
    if far.total() > 0 {
        eprintln!(
            "deltaloop-bridge: warning: the far side refused {} datagram(s) on the link ({})",
            far.total(),
            far.describe()
        );
    }
    if far_side.icmp_errors > 0 {
        eprintln!(
            "deltaloop-bridge: warning: the far side's UDP socket had {} ICMP error report(s) (port, host or network unreachable); each datagram they held back was sent again",
            far_side.icmp_errors
        );
    }
    Ok(end)
}

/// What the loop process that took the link's socket refused and dropped, added to this side's
/// counts (it says them as it exits, before this side writes the report).
fn take_process_counts(p: &mut Peer) {
    if !p.direct {
        return;
    }
    let Some(h) = &p.handoff else { return };
    let until = rt::now_ns() + 500_000_000;
    loop {
        if let Some(c) = crate::direct::read_counts(h) {
            p.udp.absorb(c);
            return;
        }
        if rt::now_ns() > until {
            return;
        }
        std::thread::sleep(Duration::from_millis(5));
    }
}

/// The warning for reply copies that reached this host too late for the record (this bridge
/// was held up past [`crate::sides::RECORD_HORIZON`] ticks), if any.
fn late_copies_warning(late: u64) -> Option<String> {
    (late > 0).then(|| {
        format!(
            "deltaloop-bridge: warning: {late} cop(ies) of the far controller's replies reached this host {} or more ticks after their state (this bridge was held up): the record had finished those ticks; each the plant applied is recorded with `reply` unknown and counted in `replies_lost`",
            crate::sides::RECORD_HORIZON
        )
    })
}

/// The far side's refusals from its `Refused` frame.
fn far_refusals(p: &[u8]) -> Option<SideRefusals> {
    SideRefusals::from_wire(p)
}

/// The warning lines for the datagrams this side (and the loop process that took its socket)
/// refused, and for the errors ICMP messages reported on its socket, if any.
pub fn refused_warning(udp: &Udp) -> Option<String> {
    let r = &udp.refused;
    let refused = (r.total() > 0).then(|| {
        let first = udp
            .last_refusal
            .as_deref()
            .map_or(String::new(), |why| format!("; the first: {why}"));
        format!(
            "deltaloop-bridge: warning: refused {} datagram(s) on the link ({}{first})",
            r.total(),
            r.describe(),
        )
    });
    let icmp = (udp.icmp_errors > 0).then(|| {
        format!(
            "deltaloop-bridge: warning: {} ICMP error report(s) (port, host or network unreachable) on the link's UDP socket; each datagram they held back was sent again",
            udp.icmp_errors
        )
    });
    match (refused, icmp) {
        (Some(a), Some(b)) => Some(format!("{a}\n{b}")),
        (a, b) => a.or(b),
    }
}

/// The link's statistics on stderr, if there is anything to say: the datagrams the emulation
/// dropped here and, on the plant's host (`counts`), the states sent again (lockstep), the
/// replies recovered from a later datagram, the states of a backlog not sent (realtime) and (a
/// warning) the replies for a state not yet sent.
pub fn link_summary(emu: &Emulation, dropped: u64, counts: Option<crate::sides::PlantHostCounts>) {
    let c = counts.unwrap_or_default();
    if c.future > 0 {
        eprintln!(
            "deltaloop-bridge: warning: left out {} repl(ies) for a state not yet sent \
             (the far controller answered a tick it was never given)",
            c.future
        );
    }
    if c.unknown > 0 || c.refused_recalls > 0 {
        eprintln!(
            "deltaloop-bridge: warning: {} repl(ies) lost on the link could not be recalled (their ticks are recorded with `reply` unknown); {} recall answer(s) refused",
            c.unknown, c.refused_recalls
        );
    }
    let (resent, recovered, stale) = (c.resent, c.recovered, c.stale);
    if emu.is_off() && resent == 0 && recovered == 0 && stale == 0 && c.lost == 0 {
        return;
    }
    let mut line = format!(
        "deltaloop-bridge: {}: {dropped} datagram(s) dropped here",
        describe(emu)
    );
    if counts.is_some() {
        line += &format!(
            ", {resent} state(s) sent again, {recovered} repl(ies) recovered from a later datagram, {} lost beyond its copies ({} recalled), {stale} state(s) of a backlog not sent (a newer one went instead)",
            c.lost, c.recalled
        );
    }
    eprintln!("{line}");
}

/// Exposed for the far side's START: tick 0's deadline on this host's clock, from the relative
/// time on the wire.
pub fn absolute_t0(relative_ns: u64) -> u64 {
    rt::now_ns().saturating_add(relative_ns)
}

/// The emulation in force (for the report line).
pub fn describe(e: &Emulation) -> String {
    format!(
        "emulated link: delay {} µs, jitter {} µs, loss {} ppm, seed {}",
        e.delay_ns / 1000,
        e.jitter_ns / 1000,
        e.loss_ppm,
        e.seed
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Regression: on the direct path the loop process's socket counted its refusals and
    /// handed its bridge the counts only, so the bridge's warning ended "first: )". The
    /// reason comes with the counts, and a warning without one names none.
    #[test]
    fn regression_the_direct_paths_refusal_warning_names_the_first_reason() {
        let (a, b) = (
            UdpSocket::bind("127.0.0.1:0").unwrap(),
            UdpSocket::bind("127.0.0.1:0").unwrap(),
        );
        a.connect(b.local_addr().unwrap()).unwrap();
        b.connect(a.local_addr().unwrap()).unwrap();
        let s = Session::generate().unwrap();
        let mut process = Udp::sealed(a, &s, End::Near, Emulation::default()).unwrap();
        b.send(b"junk").unwrap();
        std::thread::sleep(Duration::from_millis(20));
        assert!(process.recv().unwrap().is_none());
        let (bridge_end, process_end) = deltaloop_transport::handoff::pair().unwrap();
        crate::direct::counts(&process_end, &process);
        let spare = UdpSocket::bind("127.0.0.1:0").unwrap();
        let mut bridge = Udp::sealed(spare, &s, End::Near, Emulation::default()).unwrap();
        assert_eq!(refused_warning(&bridge), None);
        bridge.absorb(crate::direct::read_counts(&bridge_end).expect("the counts"));
        let line = refused_warning(&bridge).unwrap();
        assert!(
            line.contains("malformed 1") && line.contains("the first: 4 bytes"),
            "{line}"
        );
        bridge.last_refusal = None;
        let line = refused_warning(&bridge).unwrap();
        assert!(
            !line.contains("first") && line.ends_with("(malformed 1)"),
            "{line}"
        );
    }

    /// Regression: a far side grew the near host's `<law>.controller.log` to 97 MB in 0.8 s; what
    /// it sends is kept up to [`FAR_LOG_CAP`], and the cut is said once.
    #[test]
    fn regression_a_far_side_cannot_grow_the_near_log_past_its_cap() {
        let mut log = FarLog::default();
        let flood = vec![b'x'; 1000];
        let kept: Vec<String> = (0..5000).filter_map(|_| log.admit(&flood)).collect();
        let bytes: usize = kept.iter().map(|l| l.len() + 1).sum();
        assert!(bytes <= FAR_LOG_CAP + 200, "{bytes}");
        assert!(bytes > FAR_LOG_CAP - 2000, "{bytes}");
        let cuts = kept.iter().filter(|l| l.contains("dropped here")).count();
        assert_eq!(cuts, 1);
        assert!(kept.last().unwrap().contains("dropped here"));
        assert_eq!(log.admit(b"short"), None, "nothing after the cut");
    }
}
