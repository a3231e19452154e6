//! Why a tick was missed or late: the kernel's record of the loop thread's CPU over the tick's
//! window, folded into one cause. Pure and streaming: events in time order, windows in the order
//! they open, verdicts out in tick order; memory holds only the windows still open.

use crate::event::{Event, Kind, Thread};
use serde::Serialize;
use std::collections::{BTreeMap, HashMap};

/// What took a tick's time (docs/guide/misses.md).
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Cause {
    /// Another thread held the CPU while the loop thread was runnable.
    Preempted,
    /// A hard interrupt handler ran on the CPU.
    Irq,
    /// A softirq (NET_RX, TIMER, …) ran on the CPU.
    Softirq,
    /// The loop thread was not running and nothing else was: it was woken late (or not yet).
    Wakeup,
    /// The loop thread held the CPU yet made no progress and the kernel logged nothing: the
    /// hypervisor took the virtual CPU.
    Host,
    /// The loop thread's own work (the controller's compute) took the time.
    Own,
    /// Across two hosts: the datagram arrived late.
    Link,
    /// No record covers the window (events lost, or no tracing).
    Unknown,
}

impl Cause {
    pub const ALL: [Cause; 8] = [
        Cause::Preempted,
        Cause::Irq,
        Cause::Softirq,
        Cause::Wakeup,
        Cause::Host,
        Cause::Own,
        Cause::Link,
        Cause::Unknown,
    ];

    pub fn name(self) -> &'static str {
        match self {
            Cause::Preempted => "preempted",
            Cause::Irq => "irq",
            Cause::Softirq => "softirq",
            Cause::Wakeup => "wakeup",
            Cause::Host => "host",
            Cause::Own => "own",
            Cause::Link => "link",
            Cause::Unknown => "unknown",
        }
    }
}

/// A missed tick (the reply did not arrive within the torque budget) or a late one (the plant
/// woke later than a quarter period after its deadline).
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum MissKind {
    Missed,
    Late,
}

impl MissKind {
    pub fn name(self) -> &'static str {
        match self {
            MissKind::Missed => "missed",
            MissKind::Late => "late",
        }
    }
}

/// A tick to explain: the span [`from_ns`, `to_ns`] (CLOCK_MONOTONIC) in which the loop thread
/// `pid` on `cpu` had to do its part: for a missed tick the controller, from the state's
/// publication to the end of the torque budget; for a late one the plant, from its deadline to
/// its wake-up.
#[derive(Clone, Debug, PartialEq)]
pub struct Window {
    pub k: u64,
    pub kind: MissKind,
    pub cpu: usize,
    pub pid: i32,
    pub from_ns: u64,
    pub to_ns: u64,
    /// The thread's own work within the window, ns: the controller's compute, from the state
    /// received to the torque published, when it stamped both.
    pub work: Option<(u64, u64)>,
    /// The controller is across a link: which leg its stamps blame (`state leg`, `reply leg`,
    /// `far host`, `no reply`). The window is then the plant's, waiting; unless something on
    /// this host held the plant's CPU, the cause is `link`.
    pub link: Option<&'static str>,
}

/// A tick's cause.
#[derive(Clone, Debug, PartialEq)]
pub struct Verdict {
    pub k: u64,
    pub kind: MissKind,
    pub cause: Cause,
    /// The thread that held the CPU longest while the loop thread was runnable: always for
    /// `preempted`, and for any cause when it held a quarter of the window or more.
    pub culprit: Option<Thread>,
    /// The interrupt (`irq`) or softirq (`softirq`) that took the time.
    pub source: Option<String>,
    pub cpu: usize,
    /// The time the cause took out of the window, µs.
    pub lost_us: f64,
    /// The window, ns (CLOCK_MONOTONIC).
    pub from_ns: u64,
    pub to_ns: u64,
}

/// What one CPU is doing, as far as the events tell.
#[derive(Clone, Debug, Default)]
struct Cpu {
    current: Option<Thread>,
    irq: Option<String>,
    softirq: Option<String>,
    steal: Option<u64>,
}

/// One open window and where its time went, ns.
#[derive(Debug)]
struct Open {
    w: Window,
    last: u64,
    others: HashMap<i32, (Thread, u64)>,
    irq: HashMap<String, u64>,
    softirq: HashMap<String, u64>,
    wake: u64,
    own: u64,
    no_progress: u64,
    /// Time on a CPU whose state the record does not give.
    unknown: u64,
    steal_at_open: Option<u64>,
    lost_events: bool,
}

/// The streaming attribution. Feed [`Explainer::open`] each window before the first event at or
/// after its start, [`Explainer::event`] every event in time order, then [`Explainer::finish`].
pub struct Explainer {
    cpus: HashMap<usize, Cpu>,
    /// The loop threads' runnable state (running counts as runnable).
    runnable: HashMap<i32, bool>,
    open: Vec<Open>,
    /// Verdicts of `own` waiting for the CPU's next steal sample, with the steal at the window's
    /// start.
    held: Vec<(Verdict, Option<u64>)>,
    /// Verdicts not yet released, in tick order.
    ready: BTreeMap<(u64, MissKind), Verdict>,
    now: u64,
}

impl Explainer {
    /// For the loop threads `pids` (their runnable state is followed).
    pub fn new(pids: &[i32]) -> Self {
        Self {
            cpus: HashMap::new(),
            runnable: pids.iter().map(|&p| (p, false)).collect(),
            open: Vec::new(),
            held: Vec::new(),
            ready: BTreeMap::new(),
            now: 0,
        }
    }

    /// Opens a window; verdicts of windows that ended before it go to `out`.
    pub fn open(&mut self, w: Window, out: &mut impl FnMut(Verdict)) {
        self.advance(w.from_ns, out);
        let steal_at_open = self.cpus.get(&w.cpu).and_then(|c| c.steal);
        self.open.push(Open {
            last: w.from_ns,
            w,
            others: HashMap::new(),
            irq: HashMap::new(),
            softirq: HashMap::new(),
            wake: 0,
            own: 0,
            no_progress: 0,
            unknown: 0,
            steal_at_open,
            lost_events: false,
        });
    }

    /// The next event (in time order); verdicts that are final go to `out`, in tick order.
    pub fn event(&mut self, e: &Event, out: &mut impl FnMut(Verdict)) {
        // A lost-events line has no time of its own: it is taken at the last event's.
        let t = if e.t_ns == 0 { self.now } else { e.t_ns };
        self.advance(t, out);
        let cpu = self.cpus.entry(e.cpu).or_default();
        match &e.kind {
            Kind::Switch {
                prev_pid,
                prev_runnable,
                next,
            } => {
                if let Some(r) = self.runnable.get_mut(prev_pid) {
                    *r = *prev_runnable;
                }
                if let Some(r) = self.runnable.get_mut(&next.pid) {
                    *r = true;
                }
                cpu.current = Some(next.clone());
            }
            Kind::Waking { pid, .. } => {
                if let Some(r) = self.runnable.get_mut(pid) {
                    *r = true;
                }
            }
            Kind::IrqEntry { name, .. } => cpu.irq = Some(name.clone()),
            Kind::IrqExit => cpu.irq = None,
            Kind::SoftirqEntry { name } => cpu.softirq = Some(name.clone()),
            Kind::SoftirqExit => cpu.softirq = None,
            Kind::Steal { jiffies } => {
                cpu.steal = Some(*jiffies);
                let (now, on) = (t, e.cpu);
                let mut keep = Vec::new();
                for (mut v, at_open) in std::mem::take(&mut self.held) {
                    if v.cpu == on && now >= v.to_ns {
                        if at_open.is_some_and(|s| *jiffies > s) {
                            v.cause = Cause::Host;
                        }
                        self.ready.insert((v.k, v.kind), v);
                    } else {
                        keep.push((v, at_open));
                    }
                }
                self.held = keep;
            }
            Kind::Lost { .. } => {
                *cpu = Cpu::default();
                for o in self.open.iter_mut().filter(|o| o.w.cpu == e.cpu) {
                    o.lost_events = true;
                }
            }
        }
        self.release(out);
    }

    /// Every verdict left, in tick order (`own` ones whose steal was never sampled again stay
    /// `own`).
    pub fn finish(mut self, out: &mut impl FnMut(Verdict)) {
        self.advance(u64::MAX, out);
        for (v, _) in std::mem::take(&mut self.held) {
            self.ready.insert((v.k, v.kind), v);
        }
        for v in std::mem::take(&mut self.ready).into_values() {
            out(v);
        }
    }

    /// Accounts every open window up to `t` and closes those that ended.
    fn advance(&mut self, t: u64, out: &mut impl FnMut(Verdict)) {
        self.now = self.now.max(t.min(u64::MAX - 1));
        let mut i = 0;
        while i < self.open.len() {
            let o = &mut self.open[i];
            let unseen = Cpu::default();
            let cpu = self.cpus.get(&o.w.cpu).unwrap_or(&unseen);
            let runnable = self.runnable.get(&o.w.pid).copied().unwrap_or(false);
            account(o, t, cpu, runnable);
            if t >= o.w.to_ns {
                let o = self.open.swap_remove(i);
                let v = verdict(&o);
                if v.cause == Cause::Own {
                    self.held.push((v, o.steal_at_open));
                } else {
                    self.ready.insert((v.k, v.kind), v);
                }
            } else {
                i += 1;
            }
        }
        self.release(out);
    }

    /// Releases the verdicts no open or held window can precede.
    fn release(&mut self, out: &mut impl FnMut(Verdict)) {
        let first_pending = self
            .open
            .iter()
            .map(|o| o.w.k)
            .chain(self.held.iter().map(|(v, _)| v.k))
            .min();
        while let Some(entry) = self.ready.first_entry() {
            if first_pending.is_some_and(|k| entry.key().0 >= k) {
                break;
            }
            out(entry.remove());
        }
    }
}

/// Adds [o.last, t) of the window, spent as `cpu` and `runnable` say.
fn account(o: &mut Open, t: u64, cpu: &Cpu, runnable: bool) {
    let (a, b) = (o.last.max(o.w.from_ns), t.min(o.w.to_ns));
    o.last = o.last.max(t.min(o.w.to_ns));
    if b <= a {
        return;
    }
    let dt = b - a;
    if let Some(n) = &cpu.irq {
        *o.irq.entry(n.clone()).or_default() += dt;
    } else if let Some(n) = &cpu.softirq {
        *o.softirq.entry(n.clone()).or_default() += dt;
    } else {
        match &cpu.current {
            // No switch seen on this CPU yet (or since events were lost): who ran is unknown.
            None => o.unknown += dt,
            Some(th) if th.pid == o.w.pid => {
                let work =
                    o.w.work
                        .map_or(0, |(s, e)| e.min(b).saturating_sub(s.max(a)));
                o.own += work;
                o.no_progress += dt - work;
            }
            Some(th) if runnable && !th.is_idle() => {
                o.others.entry(th.pid).or_insert_with(|| (th.clone(), 0)).1 += dt;
            }
            // Idle while runnable (woken, not yet run), or asleep (not woken yet).
            Some(_) => o.wake += dt,
        }
    }
}

/// The cause that took the most of the window.
fn verdict(o: &Open) -> Verdict {
    let top = |m: &HashMap<String, u64>| {
        m.iter()
            .max_by_key(|(n, v)| (**v, std::cmp::Reverse((*n).clone())))
            .map(|(n, v)| (n.clone(), *v))
    };
    let culprit = o
        .others
        .values()
        .max_by_key(|(th, v)| (*v, std::cmp::Reverse(th.pid)))
        .cloned();
    let others: u64 = o.others.values().map(|(_, v)| v).sum();
    let (irq, softirq) = (top(&o.irq), top(&o.softirq));
    let sum = |m: &HashMap<String, u64>| m.values().sum::<u64>();
    let candidates = [
        (Cause::Preempted, others),
        (Cause::Irq, sum(&o.irq)),
        (Cause::Softirq, sum(&o.softirq)),
        (Cause::Wakeup, o.wake),
        (Cause::Host, o.no_progress),
        (Cause::Own, o.own),
        (Cause::Unknown, o.unknown),
    ];
    let (mut cause, lost) =
        candidates.into_iter().fold(
            (Cause::Unknown, 0),
            |best, c| if c.1 > best.1 { c } else { best },
        );
    // Across a link the plant waits for the datagram: unless a thread or an interrupt held its
    // CPU (or the record says nothing), the time went to the link.
    let local = matches!(
        cause,
        Cause::Preempted | Cause::Irq | Cause::Softirq | Cause::Unknown
    );
    if o.w.link.is_some() && !local {
        cause = Cause::Link;
    }
    // With events lost the record cannot say.
    if o.lost_events {
        cause = Cause::Unknown;
    }
    let span = o.w.to_ns.saturating_sub(o.w.from_ns);
    let named = |c: &(Thread, u64)| cause == Cause::Preempted || c.1 * 4 >= span;
    Verdict {
        k: o.w.k,
        kind: o.w.kind,
        cause,
        culprit: culprit.filter(|c| c.1 > 0 && named(c)).map(|c| c.0),
        source: match cause {
            Cause::Irq => irq.map(|i| i.0),
            Cause::Softirq => softirq.map(|s| s.0),
            Cause::Link => o.w.link.map(str::to_string),
            _ => None,
        },
        cpu: o.w.cpu,
        lost_us: lost as f64 / 1e3,
        from_ns: o.w.from_ns,
        to_ns: o.w.to_ns,
    }
}

/// Every verdict of `windows` (in start order) over `events` (in time order), in tick order.
pub fn explain(
    pids: &[i32],
    windows: impl IntoIterator<Item = Window>,
    events: impl IntoIterator<Item = Event>,
    mut out: impl FnMut(Verdict),
) {
    let mut x = Explainer::new(pids);
    let mut windows = windows.into_iter().peekable();
    for e in events {
        let t = if e.t_ns == 0 { x.now } else { e.t_ns };
        while let Some(w) = windows.next_if(|w| w.from_ns <= t) {
            x.open(w, &mut out);
        }
        x.event(&e, &mut out);
    }
    for w in windows {
        x.open(w, &mut out);
    }
    x.finish(&mut out);
}

#[cfg(test)]
mod tests {
    use super::*;

    const LOOP: i32 = 100;

    fn th(pid: i32, comm: &str, prio: i32) -> Thread {
        Thread {
            pid,
            comm: comm.into(),
            prio,
        }
    }

    fn switch(t_us: u64, prev: i32, runnable: bool, next: Thread) -> Event {
        Event {
            t_ns: t_us * 1000,
            cpu: 1,
            kind: Kind::Switch {
                prev_pid: prev,
                prev_runnable: runnable,
                next,
            },
        }
    }

    fn at(t_us: u64, kind: Kind) -> Event {
        Event {
            t_ns: t_us * 1000,
            cpu: 1,
            kind,
        }
    }

    fn window(k: u64, from_us: u64, to_us: u64) -> Window {
        Window {
            k,
            kind: MissKind::Missed,
            cpu: 1,
            pid: LOOP,
            from_ns: from_us * 1000,
            to_ns: to_us * 1000,
            work: None,
            link: None,
        }
    }

    fn run(windows: Vec<Window>, events: Vec<Event>) -> Vec<Verdict> {
        let mut v = Vec::new();
        explain(&[LOOP], windows, events, |x| v.push(x));
        v
    }

    /// The controller woken at 1000 µs, a FIFO 75 burner holds its CPU to 1200 µs: preempted,
    /// by the burner, 150 µs of the 150 µs budget.
    #[test]
    fn a_thread_holding_the_cpu_while_the_loop_is_runnable_is_the_culprit() {
        let burner = th(7, "burner", 24);
        let v = run(
            vec![window(3, 1000, 1150)],
            vec![
                switch(900, LOOP, false, burner.clone()),
                at(
                    1001,
                    Kind::Waking {
                        pid: LOOP,
                        target_cpu: 1,
                    },
                ),
                switch(1200, 7, false, th(LOOP, "ctl", 29)),
            ],
        );
        assert_eq!(v.len(), 1);
        assert_eq!(v[0].cause, Cause::Preempted);
        assert_eq!(v[0].culprit.as_ref(), Some(&burner));
        assert!((v[0].lost_us - 149.0).abs() < 1e-9, "{v:?}");
    }

    /// An interrupt inside the window beats the thread it interrupted; the softirq after it is
    /// shorter.
    #[test]
    fn irq_and_softirq_are_named() {
        let v = run(
            vec![window(1, 0, 100)],
            vec![
                switch(0, 0, false, th(LOOP, "ctl", 29)),
                at(
                    10,
                    Kind::IrqEntry {
                        irq: 24,
                        name: "virtio0-input.0".into(),
                    },
                ),
                at(70, Kind::IrqExit),
                at(
                    70,
                    Kind::SoftirqEntry {
                        name: "NET_RX".into(),
                    },
                ),
                at(90, Kind::SoftirqExit),
            ],
        );
        assert_eq!(v[0].cause, Cause::Irq);
        assert_eq!(v[0].source.as_deref(), Some("virtio0-input.0"));
        assert!((v[0].lost_us - 60.0).abs() < 1e-9);
        assert_eq!(v[0].culprit, None);
    }

    /// Asleep, or woken on an idle CPU: wakeup. Running inside its work: own; running outside
    /// it: host; own becomes host when the CPU's steal clock moved across the window.
    #[test]
    fn wakeup_own_and_host() {
        let v = run(
            vec![window(1, 0, 100)],
            vec![
                switch(0, LOOP, false, th(0, "swapper/1", 120)),
                switch(80, 0, true, th(LOOP, "ctl", 29)),
            ],
        );
        assert_eq!(v[0].cause, Cause::Wakeup);
        let mut own = window(2, 1000, 1100);
        own.work = Some((1_000_000, 1_100_000));
        let mut stolen = window(3, 5000, 5100);
        stolen.work = Some((5_000_000, 5_100_000));
        let v = run(
            vec![window(1, 100, 200), own, stolen],
            vec![
                switch(0, 0, false, th(LOOP, "ctl", 29)),
                at(900, Kind::Steal { jiffies: 5 }),
                at(2000, Kind::Steal { jiffies: 5 }),
                at(3000, Kind::Steal { jiffies: 5 }),
                at(6000, Kind::Steal { jiffies: 6 }),
            ],
        );
        let causes: Vec<_> = v.iter().map(|v| (v.k, v.cause)).collect();
        assert_eq!(
            causes,
            [(1, Cause::Host), (2, Cause::Own), (3, Cause::Host)]
        );
    }

    /// With no record of the CPU (no tracing, or before its first switch), the cause is unknown.
    #[test]
    fn no_record_is_unknown() {
        let v = run(vec![window(1, 0, 100)], vec![]);
        assert_eq!(v[0].cause, Cause::Unknown);
        let mut across = window(2, 0, 100);
        across.link = Some("no reply");
        assert_eq!(run(vec![across], vec![])[0].cause, Cause::Unknown);
    }

    /// Across a link the plant's wait is the link's (with the leg), unless a thread held its CPU.
    #[test]
    fn across_a_link_the_wait_is_the_links_unless_the_cpu_was_taken() {
        let mut waiting = window(1, 0, 100);
        waiting.link = Some("reply leg");
        let mut taken = window(2, 200, 300);
        taken.link = Some("state leg");
        let v = run(
            vec![waiting, taken],
            vec![
                switch(0, LOOP, false, th(0, "swapper/1", 120)),
                at(
                    150,
                    Kind::Waking {
                        pid: LOOP,
                        target_cpu: 1,
                    },
                ),
                switch(190, 0, false, th(9, "hog", 10)),
            ],
        );
        assert_eq!(v[0].cause, Cause::Link);
        assert_eq!(v[0].source.as_deref(), Some("reply leg"));
        assert_eq!(v[1].cause, Cause::Preempted);
        assert_eq!(v[1].culprit.as_ref().map(|c| c.pid), Some(9));
    }

    /// Lost events make the window unknown; windows come out in tick order even when an own
    /// verdict waits for its steal sample.
    #[test]
    fn lost_events_are_unknown_and_verdicts_keep_tick_order() {
        let mut own = window(1, 0, 100);
        own.work = Some((0, 100_000));
        let v = run(
            vec![own, window(2, 200, 300), window(3, 400, 500)],
            vec![
                switch(0, 0, false, th(LOOP, "ctl", 29)),
                switch(150, LOOP, false, th(0, "swapper/1", 120)),
                at(450, Kind::Lost { count: 3 }),
                at(
                    1000,
                    Kind::SoftirqEntry {
                        name: "TIMER".into(),
                    },
                ),
            ],
        );
        let got: Vec<_> = v.iter().map(|v| (v.k, v.cause)).collect();
        assert_eq!(
            got,
            [(1, Cause::Own), (2, Cause::Wakeup), (3, Cause::Unknown)]
        );
    }
}
