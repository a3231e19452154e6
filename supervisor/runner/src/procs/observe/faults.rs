//! How a process run ended, in words: a child's exit status or signal, the line of its log that
//! says why, and the run's [`Fault`].

use super::super::children::Pair;
use super::super::status::status_text;
use super::{Ending, Observation};
use crate::peer_text::{self, Tail};
use deltaloop_config::RemoteSide;
use deltaloop_study::record::{Fault, FaultKind};
use deltaloop_transport::wire::{ControlKind, Sender};
use std::path::Path;
use std::process::ExitStatus;

/// The line of a child's log that says why it stopped (see [`peer_text::reason`]).
fn last_line(path: &Path) -> String {
    Tail::read(path).reason()
}

/// Which process a part of a fault's cause is about: the root cause's parts come first.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum About {
    Plant,
    Controller,
    /// The supervisor's own observation (when it saw an exit): last.
    Observer,
}

/// Which process a fault of this kind is the fault of (its parts of the cause come first). A
/// set-up failure or a stop on request is the fault of the process whose exit says so (the
/// controller's first, as [`fault_kind`] ranks them).
fn culprit(kind: FaultKind, ctrl: Option<ExitStatus>) -> About {
    use FaultKind::*;
    match kind {
        PlantFailed | PlantPanicked | PlantKilled | PlantExited | PlantQuit | PlantOverrun
        | PlantStalled | PlantHung | PlantError => About::Plant,
        ControllerSilent | ControllerFailed | ControllerPanicked | ControllerKilled
        | ControllerExited | ControllerHung => About::Controller,
        Setup | Stopped => match ctrl {
            Some(s) if !s.success() && exit_kind(Sender::Controller, s) == kind => {
                About::Controller
            }
            _ => About::Plant,
        },
        Hung => About::Observer,
    }
}

/// One line saying what went wrong, or None when both children finished normally.
/// The tick is the one the plant's FAULT message names, else the tick after its last telemetry.
/// The first part of the line is about the root cause ([`fault_kind`]), not its echo.
pub(super) fn fault_cause(
    ending: &Ending,
    pair: &Pair,
    streams: &Observation<'_>,
    silence_timeout_ms: u32,
) -> Option<Fault> {
    let (plant, ctrl) = (ending.plant, ending.controller);
    let (plant_log, ctrl_log) = pair.log_paths();
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
    let kind = fault_kind(
        plant,
        ctrl,
        plant_quit,
        streams.plant_fault.as_ref().map(|f| f.kind),
    );
    let tick = streams
        .plant_fault
        .as_ref()
        .map_or(last_tel.map_or(0, |m| m.tick + 1), |f| f.tick);
    let mut parts: Vec<(About, String)> = Vec::new();
    if kind == FaultKind::PlantStalled {
        parts.push((
            About::Plant,
            format!(
                "the plant's process sent nothing for loop.silence_timeout_ms = {silence_timeout_ms} ms (stopped, or starved of CPU by the host), so the controller gave up on it"
            ),
        ));
    }
    if plant_quit {
        parts.push((
            About::Plant,
            match last_tel {
                Some(m) => format!(
                    "the plant exited (status 0) after tick {} of {n}, before the end of the run",
                    m.tick
                ),
                None => format!("the plant exited (status 0) before tick 0 of {n}"),
            },
        ));
    }
    // A child still running when the supervisor stopped it is not a cause (status None), unless
    // the other one had finished the run: then it outlived the run.
    if ctrl.is_some() && !ok(ctrl) {
        let what = ctrl.map_or("did not exit".into(), status_text);
        let line = last_line(ctrl_log);
        let who = child_name(streams, Sender::Controller, ctrl);
        parts.push((
            About::Controller,
            if line.is_empty() {
                format!("{who} {what}")
            } else {
                format!("{who} {what} ({line})")
            },
        ));
    }
    match kind {
        FaultKind::ControllerHung => parts.push((
            About::Controller,
            format!(
                "the controller did not exit after the plant's final state (tick {}): the supervisor stopped it",
                n + 1
            ),
        )),
        FaultKind::PlantHung => parts.push((
            About::Plant,
            "the plant did not exit after the controller had: the supervisor stopped it".into(),
        )),
        _ => {}
    }
    let line = last_line(plant_log);
    if plant.is_some() && !ok(plant) {
        let what = plant.map_or("did not exit".into(), status_text);
        let who = child_name(streams, Sender::Plant, plant);
        parts.push((
            About::Plant,
            if line.is_empty() {
                format!("{who} {what}")
            } else {
                format!(
                    "{who} {what}: {}",
                    line.trim_start_matches("deltaloop-plant: ")
                )
            },
        ));
    }
    // The plant said why it stopped the loop (FAULT): keep that, even if it could not finish
    // (still braking when it was stopped, or its log says something else last). Its FAULT is
    // about the controller's silence, its OVERRUN about itself.
    if let Some(f) = &streams.plant_fault
        && !line.contains(&f.cause)
    {
        // Its OVERRUN and PLANT_ERROR are about itself, its FAULT about the controller.
        let about = if matches!(f.kind, ControlKind::Overrun | ControlKind::PlantError) {
            About::Plant
        } else {
            About::Controller
        };
        parts.push((
            about,
            format!("the plant stopped the loop at tick {}: {}", f.tick, f.cause),
        ));
    }
    // How long after the dead peer's last message the supervisor saw it exit; not for a plant
    // on another host, whose stamps are on its own clock (docs/protocol.md §14), nor for a
    // child that exited because it had finished.
    let far_plant = streams.timing.across() == Some(RemoteSide::Plant);
    if let Some((noticed, who)) = ending.first_exit
        && !(far_plant && who == Sender::Plant)
        && !(who == Sender::Plant && ok(plant) && !plant_quit)
        && !(who == Sender::Controller && ok(ctrl))
    {
        let last = if who == Sender::Controller {
            last_torque.map(|t| t.t_publish_ns)
        } else {
            last_tel.map(|m| m.t_wake_ns)
        };
        if let Some(t) = last {
            parts.push((
                About::Observer,
                format!(
                    "the supervisor saw {} exit {:.1} ms after its last message",
                    child_name(
                        streams,
                        who,
                        if who == Sender::Plant { plant } else { ctrl }
                    ),
                    noticed.saturating_sub(t) as f64 * 1e-6
                ),
            ));
        }
    }
    // The root cause's parts first, the rest in the order above (a stable sort).
    let first = culprit(kind, ctrl);
    parts.sort_by_key(|(about, _)| (*about == About::Observer, *about != first));
    let cause = parts
        .into_iter()
        .map(|(_, p)| p)
        .collect::<Vec<_>>()
        .join("; ");
    // The plant's FAULT text is a peer's too: one printable line, bounded.
    Some(Fault {
        tick,
        kind,
        cause: peer_text::sanitize(cause.as_bytes(), 4 * peer_text::MAX_CHARS),
    })
}

/// What to call the child in `who`'s place that ended with `status`: the process, or, when
/// that process is on the other host and a signal ended the child, the near bridge in its
/// place (it exits with the far process's code, so a signal is its own death; regression: a
/// killed bridge was reported as "the controller was killed").
fn child_name(streams: &Observation<'_>, who: Sender, status: Option<ExitStatus>) -> &'static str {
    use std::os::unix::process::ExitStatusExt;
    let side = match who {
        Sender::Plant => RemoteSide::Plant,
        _ => RemoteSide::Controller,
    };
    let bridge =
        streams.timing.across() == Some(side) && status.is_some_and(|s| s.signal().is_some());
    match (side, bridge) {
        (RemoteSide::Controller, true) => {
            "the near bridge (deltaloop-bridge, in the place of the controller on the other host)"
        }
        (RemoteSide::Plant, true) => {
            "the near bridge (deltaloop-bridge, in the place of the plant on the other host)"
        }
        (RemoteSide::Controller, false) => "the controller",
        (RemoteSide::Plant, false) => "the plant",
    }
}

/// What kind of fault ended the run, from how the children exited (None: still running when
/// the supervisor stopped it), whether the plant quit early with status 0, and whether it sent
/// FAULT, OVERRUN or PLANT_ERROR (`plant_fault`). The root cause, not its echo:
/// 1. a child killed or panicking, whatever the other did next;
/// 2. the controller's own failure (the plant's FAULT for its silence, or for its
///    CONTROLLER_ERROR, follows from it), but not its exit on the plant's silence
///    (`EXIT_PEER_SILENT`), which is the plant's stall's echo;
/// 3. a stop of the plant on request nobody here made;
/// 4. the plant's OVERRUN (its own process woke too late) or PLANT_ERROR (its own physics
///    failed), then its stall (the controller gave up on it), then its FAULT for a controller
///    that went silent while alive;
/// 5. the plant's exit code; then who did not exit when the other had finished.
fn fault_kind(
    plant: Option<ExitStatus>,
    ctrl: Option<ExitStatus>,
    plant_quit: bool,
    plant_fault: Option<ControlKind>,
) -> FaultKind {
    let failed = |s: Option<ExitStatus>, who| s.filter(|s| !s.success()).map(|s| exit_kind(who, s));
    let (ctrl_kind, plant_kind) = (
        failed(ctrl, Sender::Controller),
        failed(plant, Sender::Plant),
    );
    let severe = |k: &FaultKind| {
        matches!(
            k,
            FaultKind::ControllerKilled
                | FaultKind::ControllerPanicked
                | FaultKind::PlantKilled
                | FaultKind::PlantPanicked
        )
    };
    let echo = |k: &FaultKind| *k == FaultKind::PlantStalled;
    let stopped = |k: &FaultKind| *k == FaultKind::Stopped;
    let ok = |s: Option<ExitStatus>| s.is_some_and(|s| s.success());
    let plants_own = |said: ControlKind| match said {
        ControlKind::Overrun => Some(FaultKind::PlantOverrun),
        ControlKind::PlantError => Some(FaultKind::PlantError),
        _ => None,
    };
    ctrl_kind
        .filter(severe)
        .or(plant_kind.filter(severe))
        .or(ctrl_kind.filter(|k| !echo(k)))
        .or(plant_kind.filter(stopped))
        .or(plant_fault.and_then(plants_own))
        .or(ctrl_kind)
        .or(plant_fault.map(|_| FaultKind::ControllerSilent))
        .or(plant_kind)
        .unwrap_or(if plant_quit {
            FaultKind::PlantQuit
        } else if ok(plant) && ctrl.is_none() {
            FaultKind::ControllerHung
        } else if ok(ctrl) && plant.is_none() {
            FaultKind::PlantHung
        } else {
            FaultKind::Hung
        })
}

/// The kind of fault a loop process's abnormal exit status says.
fn exit_kind(who: Sender, s: ExitStatus) -> FaultKind {
    use deltaloop_transport::exit::{EXIT_FAULT, EXIT_PEER_SILENT, EXIT_SETUP, EXIT_STOPPED};
    use std::os::unix::process::ExitStatusExt;
    let plant = who == Sender::Plant;
    let code = s.code().and_then(|c| u8::try_from(c).ok());
    match (s.signal(), code) {
        (Some(_), _) if plant => FaultKind::PlantKilled,
        (Some(_), _) => FaultKind::ControllerKilled,
        (_, Some(101)) if plant => FaultKind::PlantPanicked,
        (_, Some(101)) => FaultKind::ControllerPanicked,
        (_, Some(EXIT_SETUP)) => FaultKind::Setup,
        (_, Some(EXIT_STOPPED)) => FaultKind::Stopped,
        (_, Some(EXIT_FAULT)) if plant => FaultKind::PlantFailed,
        (_, Some(EXIT_FAULT)) => FaultKind::ControllerFailed,
        // The other process's silence: it is the cause, this exit its echo.
        (_, Some(EXIT_PEER_SILENT)) if plant => FaultKind::ControllerSilent,
        (_, Some(EXIT_PEER_SILENT)) => FaultKind::PlantStalled,
        _ if plant => FaultKind::PlantExited,
        _ => FaultKind::ControllerExited,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The kind of a fault from how the children ended: the root cause, not its echo (a
    /// killed controller makes the plant stop the loop and exit with its fault code).
    #[test]
    fn a_fault_is_classified_by_its_root_cause() {
        use std::os::unix::process::ExitStatusExt;
        let code = |c: i32| Some(ExitStatus::from_raw(c << 8));
        let sig = |s: i32| Some(ExitStatus::from_raw(s));
        let (ok, fault, stopped, setup) = (code(0), code(4), code(5), code(3));
        let k = |p, c, quit, said: bool| fault_kind(p, c, quit, said.then_some(ControlKind::Fault));
        assert_eq!(
            k(fault, sig(libc::SIGKILL), false, true),
            FaultKind::ControllerKilled
        );
        assert_eq!(
            k(fault, code(101), false, true),
            FaultKind::ControllerPanicked
        );
        assert_eq!(
            k(sig(libc::SIGBUS), ok, false, false),
            FaultKind::PlantKilled
        );
        assert_eq!(k(code(101), ok, false, false), FaultKind::PlantPanicked);
        assert_eq!(k(fault, ok, false, true), FaultKind::ControllerSilent);
        assert_eq!(k(fault, None, false, true), FaultKind::ControllerSilent);
        assert_eq!(k(fault, stopped, false, true), FaultKind::Stopped);
        assert_eq!(k(fault, setup, false, true), FaultKind::Setup);
        assert_eq!(k(stopped, ok, false, false), FaultKind::Stopped);
        assert_eq!(k(ok, setup, false, false), FaultKind::Setup);
        assert_eq!(k(ok, fault, false, false), FaultKind::ControllerFailed);
        assert_eq!(k(fault, ok, false, false), FaultKind::PlantFailed);
        assert_eq!(k(code(9), ok, false, false), FaultKind::PlantExited);
        assert_eq!(k(ok, code(9), false, false), FaultKind::ControllerExited);
        assert_eq!(k(ok, ok, true, false), FaultKind::PlantQuit);
        assert_eq!(k(ok, None, false, false), FaultKind::ControllerHung);
        assert_eq!(k(None, ok, false, false), FaultKind::PlantHung);
        assert_eq!(k(None, None, false, false), FaultKind::Hung);
        // OVERRUN: the plant's own stall, not the controller's silence.
        assert_eq!(
            fault_kind(fault, ok, false, Some(ControlKind::Overrun)),
            FaultKind::PlantOverrun
        );
        // PLANT_ERROR: the plant's own physics failed (the controller exited 0 on the final
        // state it was released with); a controller's own failure still ranks before it.
        let plant_error = Some(ControlKind::PlantError);
        assert_eq!(
            fault_kind(fault, ok, false, plant_error),
            FaultKind::PlantError
        );
        assert_eq!(
            fault_kind(fault, fault, false, Some(ControlKind::Fault)),
            FaultKind::ControllerFailed
        );
    }

    /// Regression: a plant stopped 3 s (SIGSTOP) was filed `controller_failed`: the controller's
    /// exit on the plant's silence is the stall's echo. With `overrun = "fault"` the plant's own
    /// OVERRUN names it; otherwise (it resumed, found no controller and sent FAULT) the stall.
    #[test]
    fn regression_a_stalled_plant_is_the_cause_not_the_controller_that_gave_up() {
        use std::os::unix::process::ExitStatusExt;
        let code = |c: i32| Some(ExitStatus::from_raw(c << 8));
        let (ok, fault, silent) = (code(0), code(4), code(6));
        assert_eq!(
            fault_kind(fault, silent, false, Some(ControlKind::Overrun)),
            FaultKind::PlantOverrun
        );
        assert_eq!(
            fault_kind(fault, silent, false, Some(ControlKind::Fault)),
            FaultKind::PlantStalled
        );
        assert_eq!(
            fault_kind(None, silent, false, None),
            FaultKind::PlantStalled
        );
        assert_eq!(fault_kind(ok, silent, false, None), FaultKind::PlantStalled);
        // A plant that really died is named as such; a foreign plant's code 6 is the
        // controller's silence.
        assert_eq!(
            fault_kind(
                Some(ExitStatus::from_raw(libc::SIGKILL)),
                silent,
                false,
                None
            ),
            FaultKind::PlantKilled
        );
        assert_eq!(
            fault_kind(silent, ok, false, None),
            FaultKind::ControllerSilent
        );
        assert_eq!(culprit(FaultKind::PlantStalled, silent), About::Plant);
        // A stop nobody here asked for is the fault of the process that says so.
        let stopped = code(5);
        assert_eq!(culprit(FaultKind::Stopped, stopped), About::Controller);
        assert_eq!(culprit(FaultKind::Stopped, ok), About::Plant);
    }
}
