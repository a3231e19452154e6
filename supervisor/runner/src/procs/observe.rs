//! Observing the loop: every message filed by tick in a fixed window, every finished tick handed
//! in order to `<law>.timing.csv`, the timing histograms and the recorder, until both children
//! exit. [`run`] is a started pair's run from START to its record: the observation allocated,
//! START, the observation, how the run ended.

use super::children::{Observed, Observer, Pair};
use super::{ProcessRun, Started};
use crate::feed::ReferenceFeed;
use crate::lawrun::{self, Keep, LawRecorder, LawRun};
use anyhow::{Result, bail};
use deltaloop_config::{Law, LoopMode, RemoteSide};
use deltaloop_study::Study;
use deltaloop_study::record::Fault;
use deltaloop_timing::{PeakRss, Seen, Timing, TimingAcc, TimingCsv};
use deltaloop_transport::ipc;
use deltaloop_transport::rt;
use deltaloop_transport::wire::{
    self, ControlKind, ControlMsg, Sender, StateMsg, TelemetryMsg, TorqueMsg,
};
use std::path::Path;
use std::process::ExitStatus;
use std::time::Duration;

use super::OnTick;

mod faults;

/// Ticks the observer holds open at most (a ring indexed by tick).
const WINDOW: u64 = 32_768;

/// How long the supervisor waits for a tick's state or telemetry, in loop time (ns), when both
/// loop processes are on this host (across the link, [`REPLY_LAG`]): the tick is finished once
/// the plant's states are this far past it. A tick that is whole (its state,
/// its telemetry, its reply; or, with a local controller, a newer reply: a controller answers in
/// order, so this state's will not come) is finished at once. The row is not rewritten after.
const GRACE_NS: u64 = 100_000_000;

/// The longest wait for a reply while the controller has answered nothing newer (ticks; 2.5 s
/// at Ts = 0.3 ms): it may still answer this state, late (held up behind a bridge, or stopped),
/// and the replay needs every state the controller answered. A reply later than that counts as
/// missed.
const REPLY_LAG: u64 = 8_192;

/// How often the supervisor hands what it wrote of `trace.<law>.part` and `<law>.timing.csv` to
/// the kernel (ns of its own clock): a killed run loses at most this much more than the
/// [`GRACE_NS`] and the recorder's open ticks.
const FLUSH_EVERY_NS: u64 = 250_000_000;

/// The open ticks, a ring of [`WINDOW`] slots.
struct Window {
    slots: Vec<Seen>,
    /// The next tick to finish.
    next: u64,
    /// The last tick kept (N + 1: the state after the run).
    last: u64,
    /// Whether each of the last [`WINDOW`] finished ticks had its reply (by slot): a reply that
    /// comes for one of them after it was finished is a second reply, counted as such.
    replied: Vec<bool>,
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
            replied: vec![false; WINDOW as usize],
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
        self.replied[(k % WINDOW) as usize] = seen.torque.is_some();
        seen
    }

    /// Whether tick k, finished already and among the last [`WINDOW`] finished, had its reply.
    fn finished_with_reply(&self, k: u64) -> bool {
        k < self.next && self.next - k <= WINDOW && self.replied[(k % WINDOW) as usize]
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
    /// The newest state seen: the loop's clock as the supervisor sees it (states are drained
    /// first, so every reply and telemetry sent before one is taken in the same drain).
    last_state: Option<u64>,
    /// [`GRACE_NS`] in ticks ([`REPLY_LAG`] across the link).
    grace: u64,
    /// The controller is across the link: a reply that did not come may yet be said lost
    /// (REPLIES_LOST), so a tick without one waits the grace.
    remote_controller: bool,
    /// The newest reply seen (the controller has answered up to its tick).
    last_torque: Option<TorqueMsg>,
    /// The newest telemetry of the loop seen.
    last_tel: Option<TelemetryMsg>,
    /// The plant's FAULT: it stopped the loop at this tick (and braked).
    plant_fault: Option<PlantSaid>,
    /// The plant's DIVERGED: its model failed at this tick.
    diverged: Option<PlantSaid>,
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
    /// Called with every finished tick, in tick order (see [`super::OnTick`]).
    on_tick: Option<OnTick<'a>>,
    /// Ticks whose replies the near bridge of a remote controller said may have been lost on
    /// the link (REPLIES_LOST: first..=last), not yet finished; at most [`LOST_RANGES`].
    replies_lost: std::collections::VecDeque<(u64, u64)>,
}

/// Ranges of REPLIES_LOST held at once; more are merged into the last (it only widens what is
/// recorded as unknown).
const LOST_RANGES: usize = 64;

/// A tick and a line from the plant's control channel (FAULT, OVERRUN, PLANT_ERROR, DIVERGED).
struct PlantSaid {
    tick: u64,
    cause: String,
    /// What it said: FAULT (the controller went silent, or reported an error), OVERRUN (its own
    /// process woke too late, `overrun = "fault"`), PLANT_ERROR (its own physics failed) or
    /// DIVERGED.
    kind: ControlKind,
}

fn max_opt(a: Option<u64>, b: u64) -> Option<u64> {
    Some(a.map_or(b, |a| a.max(b)))
}

impl<'a> Observation<'a> {
    fn new(
        rec: LawRecorder<'a>,
        timing: TimingAcc,
        csv: Option<TimingCsv>,
        on_tick: Option<OnTick<'a>>,
    ) -> Self {
        // Across the link what is missing may be held up behind a bridge (its queue lets
        // through a burst after a stall): there the wait is the longest.
        let grace = match timing.across() {
            Some(_) => REPLY_LAG,
            None => GRACE_NS.div_ceil(timing.ts_ns().max(1)).max(2),
        };
        let remote_controller = timing.across() == Some(RemoteSide::Controller);
        Self {
            window: Window::new(timing.last_tick() + 1),
            rec,
            timing,
            csv,
            last_seen: None,
            last_state: None,
            grace,
            remote_controller,
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
            on_tick,
            replies_lost: std::collections::VecDeque::with_capacity(LOST_RANGES),
        }
    }

    /// Takes everything waiting on the observer's ports, and finishes, in order, every tick that
    /// is whole or has waited long enough ([`GRACE_NS`]).
    fn drain(&mut self, obs: &Observer) -> Result<()> {
        obs.drain(&mut |m| self.file(m))?;
        self.finish_ready()
    }

    /// Finishes, in order, every tick that is whole or has waited long enough.
    fn finish_ready(&mut self) -> Result<()> {
        while let Some(now) = self.last_state
            && self.window.next < self.window.last
            && self.ready(self.window.next, now)
        {
            let t = self.window.take();
            self.finish_tick(t)?;
        }
        Ok(())
    }

    /// Whether tick k can be finished with the plant's states seen up to tick `now`.
    fn ready(&mut self, k: u64, now: u64) -> bool {
        let newer_reply = self.last_torque.is_some_and(|t| t.tick > k);
        let local = !self.remote_controller;
        let s = self.window.slot(k);
        if now >= k + REPLY_LAG {
            return true;
        }
        if s.state.is_none() || s.tel.is_none() {
            return now >= k + self.grace;
        }
        s.torque.is_some() || (newer_reply && (local || now >= k + self.grace))
    }

    /// Hands what is written of the trace part and the timing file to the kernel (a killed
    /// supervisor loses only what it has not finished). A trace that fails stops the loop (see
    /// [`observe`]) and is the run's error.
    fn flush(&mut self) -> Result<()> {
        self.rec.sink_mut().flush();
        match &mut self.csv {
            Some(csv) => csv.flush(),
            None => Ok(()),
        }
    }

    /// Files one message the observer's ports took.
    fn file(&mut self, m: Observed) -> Result<()> {
        match m {
            Observed::State(m) => {
                if m.flags & wire::STATE_FINAL != 0 && self.final_tick.is_none() {
                    self.final_tick = Some(m.tick);
                }
                if self.open(m.tick)? {
                    self.window.slot(m.tick).state = Some(m);
                    self.last_seen = max_opt(self.last_seen, m.tick);
                    self.last_state = max_opt(self.last_state, m.tick);
                }
            }
            Observed::Torque(m) => {
                if self.open(m.tick)? {
                    // The first reply is the one the plant applied (a second one for the same
                    // tick is dropped by it): keep that one (regression: the trace recorded the
                    // second, and replay disagreed with the run).
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
                } else if self.window.finished_with_reply(m.tick) {
                    // The tick was finished as soon as its first reply was in.
                    self.duplicate_replies += 1;
                }
                if self.last_torque.is_none_or(|t| t.tick < m.tick) {
                    self.last_torque = Some(m);
                }
            }
            Observed::Telemetry(m) => {
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
            Observed::Plant(m) => {
                let m = &m;
                let fault = |kind| PlantSaid {
                    tick: m.tick,
                    cause: m.text(),
                    kind,
                };
                match m.kind() {
                    Some(k @ ControlKind::Diverged) if self.diverged.is_none() => {
                        self.diverged = Some(fault(k))
                    }
                    Some(
                        k @ (ControlKind::Fault | ControlKind::Overrun | ControlKind::PlantError),
                    ) if self.plant_fault.is_none() => self.plant_fault = Some(fault(k)),
                    _ => {}
                }
            }
            Observed::Controller(m) => match m.kind() {
                Some(ControlKind::RepliesLost) => self.replies_lost(m.tick, m.ticks),
                Some(ControlKind::RepliesRefused) => self.rec.refused_replies(m.ticks, m.text()),
                _ => {}
            },
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

    /// REPLIES_LOST for ticks `first..=last`: those not yet finished are recorded with their
    /// reply unknown; those finished already (the message came too late for their rows) are
    /// counted all the same, so the run is not called whole.
    fn replies_lost(&mut self, first: u64, last: u64) {
        let last = last.min(self.window.last.saturating_sub(1));
        if first > last {
            return;
        }
        if first < self.window.next {
            let done = last.min(self.window.next - 1);
            self.rec.replies_lost_at(first, done - first + 1);
        }
        let first = first.max(self.window.next);
        if first > last {
            return;
        }
        let full = self.replies_lost.len() == LOST_RANGES;
        match self.replies_lost.back_mut() {
            Some(r) if full => *r = (r.0.min(first), r.1.max(last)),
            _ => self.replies_lost.push_back((first, last)),
        }
    }

    /// Whether tick k's reply was said lost on the link (ranges behind k are let go).
    fn reply_lost(&mut self, k: u64) -> bool {
        self.replies_lost.retain(|&(_, last)| last >= k);
        self.replies_lost
            .iter()
            .any(|&(first, last)| (first..=last).contains(&k))
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
        if self.rec.sink_mut().wants_timing()
            && let Some(cells) = deltaloop_timing::timing_cells(&seen, self.timing.across())
        {
            self.rec.sink_mut().timing(&cells);
        }
        self.timing.push(seen)?;
        if let Some(f) = self.on_tick.as_mut() {
            f(&seen);
        }
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
        // The tick the plant stopped the loop at (its FAULT or OVERRUN) never ran, whatever
        // reply came for it late (regression: a late reply to the tick of a silence fault made
        // a row with `reply` unknown, counted as missing telemetry, which the replay refused).
        let stopped_here = self.plant_fault.as_ref().is_some_and(|f| f.tick == seen.k);
        let ran = in_loop.is_some() || (seen.torque.is_some() && !stopped_here);
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
        let failed = self.diverged.as_ref().is_some_and(|d| d.tick == seen.k + 1);
        if self.reply_lost(seen.k) {
            // The controller may have answered it, and its reply been lost on the link: the
            // replay cannot know whether its controller steps here, so neither does the record.
            self.rec.reply_lost();
        } else if in_loop.is_some() || !failed {
            self.rec.applied(in_loop.as_ref());
        }
        if let Some(d) = self.diverged.as_ref().filter(|_| failed) {
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
        // The plant said it ran to a tick past the last one the supervisor saw (its FAULT,
        // OVERRUN or DIVERGED names it, or the fault the ending was classified as; the near
        // bridge of a remote plant says it for the link): the ticks between ran and were lost on
        // the way (the
        // supervisor had not taken them when the plant's samples went with the plant), and the
        // record says so instead of ending where its observation did (regression: a starved
        // supervisor recorded ticks 0..465 of a run the plant faulted at 5968, lost_ticks 0).
        let said = [&self.plant_fault, &self.diverged]
            .into_iter()
            .flatten()
            .map(|p| p.tick)
            .chain(cause.map(|f| f.tick))
            .max();
        if let Some(t) = said.filter(|&t| t > stop && !self.stopped) {
            (stop..t.min(self.window.last)).for_each(|j| self.rec.lost(j));
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

impl Ending {
    /// Whether the run was stopped on request (Ctrl-C, SIGTERM).
    fn interrupted(&self) -> bool {
        self.interrupted
    }

    /// What went wrong, in one line, or None: the children finished normally, or the run was
    /// stopped on purpose (on request, or by the divergence rule).
    fn fault(
        &self,
        pair: &Pair,
        streams: &Observation<'_>,
        silence_timeout_ms: u32,
    ) -> Option<Fault> {
        if self.interrupted || self.diverged_stop {
            return None;
        }
        faults::fault_cause(self, pair, streams, silence_timeout_ms)
    }
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
    let ts_ns = cfg.ts_ns();
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
    let mut flushed_ns = rt::now_ns();
    loop {
        streams.timing.sample_steal(rt::now_ns(), false);
        streams.drain(obs)?;
        if rt::now_ns() > flushed_ns + FLUSH_EVERY_NS {
            streams.flush()?;
            flushed_ns = rt::now_ns();
        }
        if let Some(a) = streams.answered() {
            feed.feed(&study.reference, a)?;
        }
        let (p, c) = pair.exited();
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
        let interrupted = crate::signals::interrupted();
        // A trace that cannot be written (a full disk) stops the loop too: the run ends with
        // that error, at its first failed write.
        let diverged =
            streams.stopped || streams.non_finite.is_some() || streams.rec.sink().failed();
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
    streams.timing.sample_steal(rt::now_ns(), true);
    streams.drain(obs)?;
    let (plant, controller) = pair.exited();
    Ok(Ending {
        plant,
        controller,
        first_exit,
        interrupted: stop_sent.is_some() && !diverged_stop,
        diverged_stop,
    })
}

/// The run of a pair through the handshake (`started`, of `law` in `mode`), from START until
/// both children are gone: allocates everything the observer fills, sends START, observes,
/// classifies how the run ended and finishes its record and timing. `sched_warnings` (about
/// the supervisor's own scheduling) go with the children's messages.
pub(super) fn run(
    started: Started,
    study: &Study,
    (law, mode): (Law, LoopMode),
    run_dir: &Path,
    keep: &Keep,
    on_tick: Option<OnTick<'_>>,
    sched_warnings: Vec<String>,
) -> Result<ProcessRun> {
    let Started {
        rid,
        obs,
        mut feed,
        mut pair,
    } = started;
    let cfg = &study.config;
    let n = study.reference.n as u64;
    let ts_ns = cfg.ts_ns();
    // Allocate (and touch) everything the observer fills before START, not after: the loop does
    // not wait for the supervisor (regression: a 10-minute lockstep run lost its first 32 k
    // ticks while the supervisor allocated per-tick tables after START).
    let link = deltaloop_report::link::across(cfg);
    let mut timing = TimingAcc::new(n, ts_ns, mode == LoopMode::Realtime, link)
        .with_hlogs(run_dir, &format!("{law}."));
    // The steal at each pause of the plant's clock, when the plant runs on this host.
    if mode == LoopMode::Realtime && link != Some(RemoteSide::Plant) {
        timing = timing.with_steal();
    }
    let mut sched_warnings = sched_warnings;
    // Before START: the kernel's record must cover tick 0.
    let explaining = match super::explain::Explaining::start(
        cfg,
        mode,
        &pair,
        run_dir,
        law.name(),
        &mut sched_warnings,
    ) {
        Some((x, log)) => {
            timing = timing.with_miss_log(log);
            Some(x)
        }
        None => None,
    };
    let mut streams = Observation::new(
        lawrun::recorder(study, law, keep)?,
        timing,
        cfg.record
            .timing_csv
            .then(|| TimingCsv::create(&run_dir.join(format!("{law}.timing.csv")), link))
            .transpose()?,
        // Shortened to the recorder's lifetime (a coercion Option does not do by itself).
        on_tick.map(|f| -> OnTick<'_> { f }),
    );
    let mut start = ControlMsg::new(ControlKind::Start, Sender::Supervisor);
    start.ticks = n;
    start.q0 = study.reference.q0().into();
    // Both children poll for START every ≤ 1 ms: tick 0 comes 10 ms after it. Across the link
    // START also crosses both bridges and the control connection (behind the reference chunks),
    // and each loop process takes the link's socket on it: 100 ms there.
    start.t0_ns = rt::now_ns()
        + if link.is_some() {
            100_000_000
        } else {
            10_000_000
        };
    let steal_before = deltaloop_timing::steal_jiffies();
    obs.start(start)?;

    let ending = observe(&obs, &mut feed, &mut pair, study, &mut streams)?;
    let mut child_messages = pair.messages();
    child_messages.extend(
        obs.intrusions()
            .into_iter()
            .map(|i| format!("deltaloop: {i}")),
    );
    let cause = ending.fault(&pair, &streams, study.config.loop_.silence_timeout_ms);
    let ((plant_rss, ctrl_rss), controller_label) = pair.close();
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
    let (run, mut timing) = streams.finish(ending.interrupted(), cause.as_ref())?;
    if let Some(x) = explaining {
        let mut warnings = Vec::new();
        x.finish(&mut timing, run_dir, law.name(), &mut warnings);
        child_messages.extend(
            warnings
                .into_iter()
                .map(|w| format!("deltaloop: warning: {w}")),
        );
    }
    timing.steal =
        deltaloop_timing::steal_ms_between(&steal_before, &deltaloop_timing::steal_jiffies());
    timing.peak_rss = PeakRss::from_kib(own_peak_rss_kib(), plant_rss, ctrl_rss);
    if timing.link.is_some() {
        let path = deltaloop_link_setup::LinkReport::path(&run_dir.join("config.toml"), &rid);
        timing.link_report = deltaloop_link_setup::LinkReport::read(&path);
        // The supervisor's copy is in summary.json; the file was only the way here.
        let _ = std::fs::remove_file(&path);
        if let Some(n) = deltaloop_timing::link_refusals_note(timing.link_report.as_ref()) {
            child_messages.push(format!("deltaloop: warning: {n}"));
        }
    }
    Ok(ProcessRun {
        controller_label,
        fault: cause,
        interrupted: ending.interrupted(),
        run_id: rid,
        run,
        timing,
        child_messages,
    })
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

#[cfg(test)]
mod tests {
    use super::*;
    use deltaloop_config::{Law, RunConfig};
    use deltaloop_study::record::FaultKind;

    /// An observation of a run of S2 that saw ticks 0..10 whole, and nothing after.
    fn seen_up_to_tick_9(study: &Study) -> Observation<'_> {
        let n = study.reference.n as u64;
        let rec = lawrun::recorder(study, Law::Tdc, &lawrun::Keep::default()).unwrap();
        let mut obs = Observation::new(rec, TimingAcc::new(n, 300_000, false, None), None, None);
        for k in 0..10u64 {
            let row = study.reference.row(k as usize).joint;
            let state = StateMsg {
                tick: k,
                q: row.q.into(),
                qd: row.qd.into(),
                q_true: row.q.into(),
                qd_true: row.qd.into(),
                ..StateMsg::default()
            };
            let slot = obs.window.slot(k);
            slot.state = Some(state);
            slot.torque = Some(TorqueMsg {
                tick: k,
                ..TorqueMsg::default()
            });
            slot.tel = Some(TelemetryMsg {
                tick: k,
                ..TelemetryMsg::default()
            });
            obs.last_seen = Some(k);
        }
        obs
    }

    fn s2() -> Study {
        let cfg =
            RunConfig::from_toml_str("name = \"t\"\n[scenario]\npath = \"s2\"\n", None).unwrap();
        Study::new(cfg).unwrap()
    }

    /// A whole tick is finished at once (the e2e regression test: a killed run lost its last
    /// 2.5 s when a tick was finished only 8192 ticks after it); a tick without its reply, once
    /// a local controller has answered a newer state; one without its telemetry, once the
    /// plant's states are [`GRACE_NS`] past it; one whose reply has not come while the
    /// controller answered nothing newer, only after [`REPLY_LAG`] ticks.
    #[test]
    fn ticks_are_finished_once_whole_or_waited_for() {
        let study = s2();
        let mut obs = seen_up_to_tick_9(&study);
        obs.last_state = Some(9);
        obs.finish_ready().unwrap();
        assert_eq!(obs.window.next, 10, "ticks 0..=9 are whole");
        // Tick 10: its state, and telemetry saying the plant missed the reply.
        let row = study.reference.row(10).joint;
        let state = StateMsg {
            tick: 10,
            q: row.q.into(),
            q_true: row.q.into(),
            ..StateMsg::default()
        };
        let missed = TelemetryMsg {
            tick: 10,
            flags: wire::TEL_MISSED,
            ..TelemetryMsg::default()
        };
        obs.window.slot(10).state = Some(state);
        obs.window.slot(10).tel = Some(missed);
        obs.last_state = Some(11);
        obs.finish_ready().unwrap();
        assert_eq!(obs.window.next, 10, "its reply may still come");
        obs.last_torque = Some(TorqueMsg {
            tick: 11,
            ..TorqueMsg::default()
        });
        obs.finish_ready().unwrap();
        assert_eq!(obs.window.next, 11, "the controller answered a newer state");
        // Tick 11: no telemetry yet.
        obs.window.slot(11).state = Some(StateMsg { tick: 11, ..state });
        obs.last_state = Some(11 + obs.grace - 1);
        obs.finish_ready().unwrap();
        assert_eq!(obs.window.next, 11);
        obs.last_state = Some(11 + obs.grace);
        obs.finish_ready().unwrap();
        assert_eq!(obs.window.next, 12, "waited the grace");
        assert_eq!(obs.grace, 334, "0.1 s at Ts = 0.3 ms");
        // Tick 12: applied, by the telemetry, but the reply's copy is still on its way (late
        // replies are recorded: the replay needs every state the controller answered).
        obs.window.slot(12).state = Some(StateMsg { tick: 12, ..state });
        obs.window.slot(12).tel = Some(TelemetryMsg {
            tick: 12,
            ..TelemetryMsg::default()
        });
        obs.last_state = Some(12 + REPLY_LAG - 1);
        obs.finish_ready().unwrap();
        assert_eq!(obs.window.next, 12);
        obs.last_state = Some(12 + REPLY_LAG);
        obs.finish_ready().unwrap();
        assert!(obs.window.next > 12);
    }

    /// Regression: a supervisor starved of the CPU saw the loop up to tick 465, the plant's
    /// samples after it went with the plant, and the plant's FAULT said tick 5968; the record
    /// ended at 465 with `lost_ticks` 0, as if the loop had stopped there. The ticks the plant
    /// said it ran are lost, and counted.
    #[test]
    fn regression_ticks_the_plant_ran_past_what_the_supervisor_saw_are_counted_lost() {
        let study = s2();
        let mut obs = seen_up_to_tick_9(&study);
        obs.plant_fault = Some(PlantSaid {
            tick: 100,
            cause: "no torque within the budget".into(),
            kind: ControlKind::Fault,
        });
        let fault = Fault {
            tick: 100,
            kind: FaultKind::ControllerSilent,
            cause: "no torque within the budget".into(),
        };
        let (run, _) = obs.finish(false, Some(&fault)).unwrap();
        assert_eq!(run.end.lost_ticks, 90, "ticks 10..100");
        assert_eq!(run.end.first_lost, Some(10));
    }

    /// Regression: with the plant across the link, a starved supervisor saw ticks 0..672 of a
    /// run whose link went silent at tick 4929 (the near bridge's fault; no FAULT of the plant's
    /// reached this host), and trace.csv ended at 672 with `lost_ticks` 0. The fault's own tick
    /// counts the ticks between as lost.
    #[test]
    fn regression_a_fault_past_what_the_supervisor_saw_counts_the_ticks_between_lost() {
        let study = s2();
        let obs = seen_up_to_tick_9(&study);
        let fault = Fault {
            tick: 100,
            kind: FaultKind::PlantFailed,
            cause: "the link to the plant's host went silent".into(),
        };
        let (run, _) = obs.finish(false, Some(&fault)).unwrap();
        assert_eq!(run.end.lost_ticks, 90, "ticks 10..100");
        assert_eq!(run.end.first_lost, Some(10));
    }

    /// Regression: the plant stopped the loop at tick 10 (controller silent) and the reply to
    /// state 10 came after, late; the record got a row 10 with `reply` unknown (its telemetry
    /// "missing"), which `replay` refused as a lost tick. The tick the plant stopped at never
    /// ran: the record ends before it, as it does when no reply comes at all.
    #[test]
    fn regression_a_late_reply_to_the_tick_the_plant_stopped_at_makes_no_row() {
        let study = s2();
        let mut obs = seen_up_to_tick_9(&study);
        let row = study.reference.row(10).joint;
        let slot = obs.window.slot(10);
        slot.state = Some(StateMsg {
            tick: 10,
            q: row.q.into(),
            q_true: row.q.into(),
            ..StateMsg::default()
        });
        slot.torque = Some(TorqueMsg {
            tick: 10,
            ..TorqueMsg::default()
        });
        obs.last_seen = Some(10);
        let cause = "no torque within the budget for 1000 consecutive ticks";
        obs.plant_fault = Some(PlantSaid {
            tick: 10,
            cause: cause.into(),
            kind: ControlKind::Fault,
        });
        let fault = Fault {
            tick: 10,
            kind: FaultKind::ControllerSilent,
            cause: cause.into(),
        };
        let (run, _) = obs.finish(false, Some(&fault)).unwrap();
        assert_eq!(run.end.records, 10, "ticks 0..=9");
        assert_eq!(run.end.no_telemetry, 0);
        assert_eq!(run.end.lost_ticks, 0);
        assert_eq!(run.end.status_tick(), Some(10));
    }

    /// REPLIES_LOST from the near bridge of a remote controller: the ticks it names are
    /// recorded with their reply unknown and counted (the run lost data, the first such tick
    /// named), however the recorded reply looked; ticks it names after they were finished are
    /// counted all the same.
    #[test]
    fn ticks_whose_replies_were_lost_on_the_link_are_recorded_unknown_and_counted() {
        let study = s2();
        let mut obs = seen_up_to_tick_9(&study);
        obs.replies_lost(3, 5);
        obs.replies_lost(40, 30); // an empty range: nothing
        for _ in 0..2 {
            let t = obs.window.take();
            obs.finish_tick(t).unwrap();
        }
        obs.replies_lost(0, 0); // finished already
        let fault = Fault {
            tick: 10,
            kind: FaultKind::ControllerSilent,
            cause: "no torque within the budget".into(),
        };
        let (run, _) = obs.finish(false, Some(&fault)).unwrap();
        assert_eq!(run.end.records, 10);
        assert_eq!(run.end.replies_lost, 4, "ticks 3..=5 and 0");
        assert_eq!(run.end.first_reply_lost, Some(0));
        assert_eq!(run.end.no_telemetry, 0);
        assert!(run.end.lost_data_text().contains("lost on the link"));
    }
}
