//! `deltaloop top [RUN_ID]`: watch a live run from outside, through the spare observer slots the
//! loop's services keep (`ipc::SPARE`: one subscriber on `state`, `telemetry` and `control`, and
//! one spare node). It only reads: it has no publisher, its subscribers use the services' safe
//! overflow (a slow `top` loses its own oldest samples and says how many; the loop's publishers
//! never wait for it), and it leaves the run's processes and files alone.
//!
//! One cost falls on the loop: iceoryx2 connects a publisher to a new subscriber on the
//! publisher's next send (it maps the subscriber's queue), so the plant's first send after `top`
//! attaches or leaves does that set-up once.

pub mod find;
pub mod relay;
pub mod view;

use anyhow::{Context, Result, anyhow, bail};
use deltaloop_config::{Law, LoopMode, RunConfig};
use deltaloop_study::Study;
use deltaloop_timing::live::LiveStats;
use deltaloop_transport::ipc::{self, IpcContext, OBSERVER_BUFFER};
use deltaloop_transport::observe;
use deltaloop_transport::wire::{self, ControlKind, Sender};
use find::RunInfo;
use relay::Relay;
use std::net::SocketAddr;
use std::time::{Duration, Instant};
use view::Status;

/// How often the ports are drained (the screen refreshes at its own interval).
const DRAIN: Duration = Duration::from_millis(20);
/// How often `top` checks that the run's plant node is still alive.
const LIVENESS: Duration = Duration::from_secs(1);

/// The observer's ports on one run.
struct Watch {
    state: ipc::StateIn,
    telemetry: ipc::TelemetryIn,
    control: ipc::ControlIn,
    /// The replies (only for `--foxglove`: the view draws them; the slot is left free otherwise).
    torque: Option<ipc::TorqueIn>,
    _node: ipc::RunNode,
}

/// Why attaching failed, in words the user can act on.
fn attach_error(run_id: &str, what: &str, detail: &str) -> anyhow::Error {
    if detail.contains("ExceedsMax") {
        anyhow!(
            "cannot watch run {run_id}: its spare observer slot on `{what}` is taken (another `deltaloop top` or observer is attached; the run keeps one spare slot)"
        )
    } else if detail.contains("DoesNotExist") {
        anyhow!("run {run_id} has no `{what}` service (it ended, or it is not a deltaloop run)")
    } else {
        anyhow!("cannot watch run {run_id}: iceoryx2: open `{what}`: {detail}")
    }
}

impl Watch {
    /// Opens (never creates) the run's services and subscribes. Insists on safe overflow: an
    /// observer on a service without it could make the loop's publishers wait.
    fn attach(run_id: &str, replies: bool) -> Result<Self> {
        // A `top` killed outright (SIGKILL) keeps its subscriber slots until its node is
        // removed: reclaim them, so the slot is refused only while a live observer holds it.
        find::remove_dead_observers(run_id);
        let node = ipc::node("top", run_id).map_err(|e| {
            anyhow!("cannot watch run {run_id}: {e} (the run's spare node is taken?)")
        })?;
        let fail =
            |what: &'static str| move |e: ipc::IpcError| attach_error(run_id, what, &e.detail);
        Ok(Self {
            telemetry: observe::telemetry(&node, run_id, OBSERVER_BUFFER)
                .map_err(fail("telemetry"))?,
            state: observe::state(&node, run_id, OBSERVER_BUFFER).map_err(fail("state"))?,
            control: observe::control(&node, run_id, Sender::Plant, 64)
                .map_err(fail(ipc::control_service(Sender::Plant)))?,
            torque: if replies {
                Some(observe::torque(&node, run_id, OBSERVER_BUFFER).map_err(fail("torque"))?)
            } else {
                None
            },
            _node: node,
        })
    }
}

/// What `top` knows of the run it watches.
struct Watched {
    info: RunInfo,
    /// The reference (for the tracking error) and N, from the run's config.
    study: Option<Study>,
    stats: LiveStats,
    status: Status,
    /// Why the plant stopped the loop, from the control channel.
    stop_reason: Option<String>,
    last_liveness: Instant,
}

impl Watched {
    fn new(info: RunInfo) -> Self {
        let study = info
            .config
            .as_ref()
            .and_then(|c| RunConfig::from_file(c).ok())
            .and_then(|c| Study::new(c).ok());
        let realtime = info.mode == Some(LoopMode::Realtime);
        let mut stats = LiveStats::new(realtime);
        if let Some(st) = &study {
            stats = stats.with_period(st.config.ts_ns());
        }
        Self {
            info,
            study,
            stats,
            status: Status::Waiting,
            stop_reason: None,
            last_liveness: Instant::now(),
        }
    }

    /// N + 1: the ticks the loop will run, if the config is known.
    fn total(&self) -> Option<u64> {
        self.study.as_ref().map(|s| s.reference.n as u64 + 1)
    }

    /// Takes everything waiting and updates the status (and the Foxglove view, if one is served).
    fn drain(&mut self, w: &Watch, mut relay: Option<&mut Relay<'_, LiveBus>>) -> Result<()> {
        while let Some(m) = w.telemetry.receive().ipc("receive telemetry")? {
            self.stats.telemetry(&m);
            if let Some(r) = relay.as_deref_mut() {
                r.telemetry(&m);
            }
            if self.status == Status::Waiting {
                self.status = Status::Running;
            }
        }
        if let Some(t) = &w.torque {
            while let Some(m) = t.receive().ipc("receive torque")? {
                if let Some(r) = relay.as_deref_mut() {
                    r.torque(&m);
                }
            }
        }
        while let Some(s) = w.state.receive().ipc("receive state")? {
            if s.flags & wire::STATE_FINAL != 0 {
                self.status = match self.stop_reason.take() {
                    Some(why) => Status::Stopped { why },
                    None => Status::Completed { tick: s.tick },
                };
                continue;
            }
            if let Some(r) = relay.as_deref_mut() {
                r.state(&s);
            }
            if let Some(st) = &self.study
                && s.tick <= st.reference.n as u64 + 1
            {
                self.stats
                    .state(&s, st.reference.row(s.tick as usize).joint.q);
            }
        }
        while let Some(m) = w.control.receive().ipc("receive control")? {
            // The text is the peer's: shown on the terminal only as one escaped line.
            let text = || {
                deltaloop_runner::peer_text::sanitize(
                    m.text().as_bytes(),
                    deltaloop_runner::peer_text::MAX_CHARS,
                )
            };
            let why = match m.kind() {
                Some(ControlKind::Fault | ControlKind::Overrun | ControlKind::PlantError) => {
                    format!("fault at tick {}: {}", m.tick, text())
                }
                Some(ControlKind::Diverged) => format!("diverged at tick {}: {}", m.tick, text()),
                Some(ControlKind::Stopped) => format!("stopped at tick {}: {}", m.tick, text()),
                _ => continue,
            };
            match &mut self.status {
                Status::Completed { .. } => self.status = Status::Stopped { why },
                Status::Stopped { .. } => {}
                _ => {
                    self.stop_reason.get_or_insert(why);
                }
            }
        }
        if !self.status.ended() && self.last_liveness.elapsed() >= LIVENESS {
            self.last_liveness = Instant::now();
            if !find::is_live(&self.info.run_id) {
                self.status = Status::Stopped {
                    why: self
                        .stop_reason
                        .clone()
                        .unwrap_or_else(|| "the run's plant is gone".into()),
                };
            }
        }
        if let Some(r) = relay {
            r.flush(false)?;
        }
        Ok(())
    }

    fn lines(&self) -> Vec<String> {
        view::lines(
            &self.info,
            self.total(),
            &self.stats.snapshot(),
            &self.status,
        )
    }

    fn plain(&self) -> String {
        view::plain(&self.info, &self.stats.snapshot(), &self.status)
    }
}

/// Picks the run: the one given (it must be live), or the only live one.
fn pick(run_id: Option<String>) -> Result<String> {
    let live = find::live_run_ids();
    match run_id {
        Some(r) if live.contains(&r) => Ok(r),
        Some(r) => bail!(
            "no live run with id `{r}`{}",
            if live.is_empty() {
                " (no deltaloop run is live on this machine)".to_string()
            } else {
                format!("; live runs: {}", live.join(", "))
            }
        ),
        None => match live.as_slice() {
            [] => bail!(
                "no deltaloop run is live on this machine (top watches lockstep and realtime runs: `deltaloop run CONFIG --mode realtime`, `deltaloop soak CONFIG --duration 10m`)"
            ),
            [one] => Ok(one.clone()),
            many => {
                let list: Vec<String> = many
                    .iter()
                    .map(|r| format!("  {}", find::run_info(r).describe()))
                    .collect();
                bail!(
                    "{} runs are live; choose one: deltaloop top RUN_ID\n{}",
                    many.len(),
                    list.join("\n")
                )
            }
        },
    }
}

/// Options of `deltaloop top`.
#[derive(Clone, Debug)]
pub struct Options {
    pub run_id: Option<String>,
    /// One `key=value` line per refresh on stdout instead of the screen; ends with the run.
    pub plain: bool,
    /// Time between refreshes.
    pub interval: Duration,
    /// Also serve the run to Foxglove over its WebSocket protocol on this (loopback) address.
    pub foxglove: Option<SocketAddr>,
}

/// The live server's bus (feature `foxglove`); without the feature there is none to make.
#[cfg(feature = "foxglove")]
type LiveBus = deltaloop_report::mcap::server::Server;
#[cfg(not(feature = "foxglove"))]
enum LiveBus {}

#[cfg(not(feature = "foxglove"))]
impl deltaloop_report::mcap::Bus for LiveBus {
    fn schema(&mut self, _: &'static str, _: &str, _: &str) -> Result<u16> {
        match *self {}
    }
    fn channel(&mut self, _: u16, _: &str, _: &str) -> Result<u16> {
        match *self {}
    }
    fn write(&mut self, _: u16, _: u64, _: &[u8]) -> Result<()> {
        match *self {}
    }
}

/// Starts the Foxglove server on `addr`.
fn serve(addr: SocketAddr) -> Result<LiveBus> {
    #[cfg(feature = "foxglove")]
    {
        LiveBus::start(addr)
    }
    #[cfg(not(feature = "foxglove"))]
    {
        bail!(
            "--foxglove {addr}: this deltaloop was built without the `foxglove` feature (build it with: cargo build --release --features foxglove)"
        )
    }
}

/// The robot is drawn at about this rate in the live view (Hz of the run's clock).
const SCENE_HZ: f64 = 30.0;
/// How often the reference path is sent again, for clients that connect late.
const REFERENCE_EVERY: Duration = Duration::from_secs(2);

/// The Foxglove view of a run, while `top` watches it.
struct Serving<'a> {
    relay: Option<Relay<'a, LiveBus>>,
    last_reference: Instant,
}

impl<'a> Serving<'a> {
    fn new(addr: Option<SocketAddr>, study: Option<&'a Study>, law: Option<Law>) -> Result<Self> {
        let relay = match addr {
            None => None,
            Some(addr) => {
                let (Some(study), Some(law)) = (study, law) else {
                    bail!(
                        "--foxglove: cannot read this run's config or law (its processes carry no --config/--law)"
                    );
                };
                let bus = serve(addr)?;
                let every = (1.0 / (SCENE_HZ * study.config.loop_.ts_s)).ceil().max(1.0) as u64;
                Some(Relay::new(bus, study, law, every)?)
            }
        };
        Ok(Self {
            relay,
            last_reference: Instant::now(),
        })
    }

    fn relay(&mut self) -> Option<&mut Relay<'a, LiveBus>> {
        if let Some(r) = &mut self.relay
            && self.last_reference.elapsed() >= REFERENCE_EVERY
        {
            self.last_reference = Instant::now();
            // A failed re-send shows at the next flush; the view goes on.
            let _ = r.reference_again();
        }
        self.relay.as_mut()
    }

    /// The run ended: the last rows and how it ended, then a moment for the clients to take
    /// them before the server closes.
    fn finish(&mut self, status: &Status) -> Result<()> {
        if let Some(r) = self.relay.take() {
            let (ok, how) = match status {
                Status::Completed { tick } => (true, format!("run completed at tick {tick}")),
                Status::Stopped { why } => (false, format!("run stopped: {why}")),
                _ => (false, "top left before the run ended".to_string()),
            };
            // The server closes when the bus is dropped, after this pause.
            let _bus = r.finish(ok, &how)?;
            std::thread::sleep(Duration::from_millis(500));
        }
        Ok(())
    }
}

/// Runs `deltaloop top`.
pub fn run(opts: Options) -> Result<()> {
    if let Some(addr) = opts.foxglove
        && !cfg!(feature = "foxglove")
    {
        serve(addr)?;
    }
    let rid = pick(opts.run_id)?;
    let info = find::run_info(&rid);
    let law = info.law;
    let watch = Watch::attach(&rid, opts.foxglove.is_some())?;
    let mut watched = Watched::new(info);
    // The view's own copy of the study (the relay's recorder borrows it for the whole watch).
    let study = opts
        .foxglove
        .and(watched.study.as_ref())
        .map(|s| Study::new(s.config.clone()))
        .transpose()?;
    let mut serving = Serving::new(opts.foxglove, study.as_ref(), law)?;
    #[cfg(feature = "foxglove")]
    if let Some(r) = &serving.relay {
        eprintln!(
            "deltaloop top: serving run {rid} to Foxglove on ws://{} (Open connection → Foxglove WebSocket; layout: examples/foxglove/deltaloop-layout.json)",
            r.bus().addr()
        );
    }
    let interactive = !opts.plain && std::io::IsTerminal::is_terminal(&std::io::stdout());
    let watched_out = if interactive {
        screen(&watch, &mut watched, &mut serving, opts.interval)
    } else {
        plain(&watch, &mut watched, &mut serving, opts.interval)
    };
    serving.finish(&watched.status)?;
    watched_out
}

/// `--plain`: a line per refresh until the run ends (or a signal).
fn plain(watch: &Watch, w: &mut Watched, sv: &mut Serving, interval: Duration) -> Result<()> {
    use std::io::Write;
    let mut next = Instant::now();
    loop {
        w.drain(watch, sv.relay())?;
        let ended = w.status.ended();
        if Instant::now() >= next || ended {
            next = Instant::now() + interval;
            let mut out = std::io::stdout().lock();
            // A closed pipe ends top, not the run.
            if writeln!(out, "{}", w.plain())
                .and_then(|_| out.flush())
                .is_err()
            {
                return Ok(());
            }
        }
        if ended || deltaloop_runner::signals::interrupted() {
            return Ok(());
        }
        std::thread::sleep(DRAIN);
    }
}

/// Puts the terminal back however `screen` ends.
struct Restore;

impl Drop for Restore {
    fn drop(&mut self) {
        ratatui::restore();
    }
}

/// The full-screen view: refreshes every `interval`; `q`, Esc or Ctrl-C quits; once the run has
/// ended it says so and waits for a key.
fn screen(watch: &Watch, w: &mut Watched, sv: &mut Serving, interval: Duration) -> Result<()> {
    use crossterm::event::{self, Event, KeyCode, KeyEventKind, KeyModifiers};
    use ratatui::style::{Modifier, Style};
    use ratatui::text::Line;
    use ratatui::widgets::{Block, Paragraph};
    let mut term = ratatui::try_init().context("cannot set up the terminal")?;
    let _restore = Restore;
    let mut next = Instant::now();
    loop {
        w.drain(watch, sv.relay())?;
        let ended = w.status.ended();
        if Instant::now() >= next || ended {
            next = Instant::now() + interval;
            let mut lines: Vec<Line> = w.lines().into_iter().map(Line::from).collect();
            lines.push(Line::from(""));
            lines.push(
                Line::from(if ended {
                    "the run has ended: press any key to leave"
                } else {
                    "q: quit (the run goes on)"
                })
                .style(Style::default().add_modifier(Modifier::REVERSED)),
            );
            term.draw(|f| {
                let block = Block::bordered().title(" deltaloop top ");
                f.render_widget(Paragraph::new(lines).block(block), f.area());
            })
            .context("cannot draw")?;
        }
        if deltaloop_runner::signals::interrupted() {
            return Ok(());
        }
        if event::poll(DRAIN).context("cannot read the terminal")?
            && let Event::Key(k) = event::read().context("cannot read the terminal")?
            && k.kind == KeyEventKind::Press
        {
            let quit = matches!(
                k.code,
                KeyCode::Char('q') | KeyCode::Char('Q') | KeyCode::Esc
            ) || (k.code == KeyCode::Char('c')
                && k.modifiers.contains(KeyModifiers::CONTROL));
            if quit || ended {
                return Ok(());
            }
        }
    }
}
