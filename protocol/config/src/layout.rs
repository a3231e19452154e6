//! The `[loop.realtime]` and `[loop.lockstep]` layouts: where and how the two loop processes run.
//! [`Layout`] is the TOML table (every key optional; the resolved config lists them all),
//! filled with its mode's defaults when the file is read; [`ResolvedLayout`] is the same layout
//! in real types, which the processes and the supervisor act on.

use crate::error::ConfigError;
use crate::key::range;
use crate::keys::LAYOUT;
use serde::{Deserialize, Serialize};

/// Where and how the two loop processes run in one mode. Missing keys take the mode's default
/// (see [`Layout::realtime_default`], [`Layout::lockstep_default`]); the resolved config lists all.
#[derive(Clone, Debug, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Layout {
    /// CPU for the plant process (−1: not pinned).
    pub plant_cpu: Option<i32>,

    /// CPU for the controller process (−1: not pinned).
    pub controller_cpu: Option<i32>,

    /// CPU for the supervisor's collector (−1: not pinned).
    pub supervisor_cpu: Option<i32>,

    /// SCHED_FIFO priority of the plant, 1..=99 (0: SCHED_OTHER).
    pub plant_priority: Option<i32>,

    /// SCHED_FIFO priority of the controller, 1..=99 (0: SCHED_OTHER).
    pub controller_priority: Option<i32>,

    /// How long a process busy-polls for its peer's message before blocking, µs.
    pub spin_us: Option<u32>,

    /// mlockall in both loop processes.
    pub lock_memory: Option<bool>,

    /// Realtime: the plant sleeps until this long before each deadline and busy-waits the rest,
    /// absorbing the timer's wake-up latency, µs (0: sleep to the deadline). At most one control
    /// period (Ts in µs).
    pub wake_early_us: Option<u32>,

    /// Realtime: the controller knows the schedule (t0, Ts) from START; it sleeps until this
    /// long before each deadline, then polls for the state (up to `spin_us` past the deadline)
    /// before it blocks on the wake-up event, µs. −1: it blocks on the event right after each
    /// reply and is woken by the plant's notification. At most one period. Lockstep ignores it.
    pub controller_wake_early_us: Option<i32>,

    /// What a process does between two looks for its peer's message while it polls: `spin` on
    /// its CPU, or `yield` the CPU to a peer at the same SCHED_FIFO priority on the same CPU
    /// (plant and controller share one CPU without a wake-up notification).
    pub poll: Option<Poll>,
}

/// What a polling process does between two looks for its peer's message.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "kebab-case")]
pub enum Poll {
    /// Busy-wait (a spin-loop hint): for a peer on another CPU.
    #[default]
    Spin,

    /// `sched_yield`: the CPU goes to a peer of the same SCHED_FIFO priority waiting on it, and
    /// comes back when that peer yields or sleeps. Needs plant and controller on one CPU at one
    /// priority (checked): a process of lower priority would never get the CPU from a yield.
    Yield,
}
impl Layout {
    /// Realtime default, the fewest misses measured on a 2-vCPU VM: plant and controller share
    /// CPU 1 under SCHED_FIFO (plant above controller); the plant wakes 80 µs early and blocks on
    /// the reply's wake-up, the controller sleeps until 50 µs before each deadline and polls for
    /// the state, so it is already running when the plant hands over the CPU. The supervisor on
    /// CPU 0. A freeze of one virtual CPU by the host stalls plant and controller together: late
    /// wakes, not misses.
    pub fn realtime_default() -> Self {
        Self {
            plant_cpu: Some(1),
            controller_cpu: Some(1),
            supervisor_cpu: Some(0),
            plant_priority: Some(80),
            controller_priority: Some(70),
            spin_us: Some(0),
            lock_memory: Some(true),
            wake_early_us: Some(80),
            controller_wake_early_us: Some(50),
            poll: Some(Poll::Spin),
        }
    }

    /// The shortest round trip: plant on CPU 1, controller on CPU 0, both SCHED_FIFO; the plant
    /// polls for the reply through the budget, both sleep until 200 µs before each deadline and
    /// poll from there; neither wakes a peer that is polling (docs/protocol.md §6.1). Each polls
    /// about two thirds of every 300 µs period, so a vCPU that the host wakes up to 200 µs late
    /// still publishes and answers on time (the measurements behind the 200 µs are in
    /// docs/bench/README.md). The supervisor shares CPU 0 as SCHED_OTHER.
    /// Needs CPUs the host does not take away: a virtual CPU frozen for 30 ms is 100 misses in
    /// a row.
    pub fn realtime_split_cpus() -> Self {
        Self {
            plant_cpu: Some(1),
            controller_cpu: Some(0),
            supervisor_cpu: Some(0),
            plant_priority: Some(80),
            controller_priority: Some(70),
            spin_us: Some(150),
            lock_memory: Some(true),
            wake_early_us: Some(200),
            controller_wake_early_us: Some(200),
            poll: Some(Poll::Spin),
        }
    }

    /// Plant and controller on CPU 1 at the same SCHED_FIFO priority, handing the CPU to each
    /// other with `sched_yield` (`poll = "yield"`): the plant wakes 80 µs early and yields while
    /// it waits for the reply, the controller sleeps until 50 µs before each deadline and yields
    /// while it waits for the state and once after each reply; no notifications. Two context
    /// switches per round trip instead of two notifications and two wake-ups, and, as in the
    /// default, a host that freezes CPU 1 stalls both together. The plant cannot preempt its
    /// controller here: a reply computed for longer than the budget delays the plant's next wake
    /// as well (it is still a miss). The supervisor on CPU 0.
    pub fn realtime_one_cpu_yield() -> Self {
        Self {
            controller_priority: Some(80),
            spin_us: Some(150),
            poll: Some(Poll::Yield),
            ..Self::realtime_default()
        }
    }

    /// Lockstep default, the highest cycle rate: one CPU each, busy-polling before blocking.
    pub fn lockstep_default() -> Self {
        Self {
            plant_cpu: Some(0),
            controller_cpu: Some(1),
            supervisor_cpu: Some(-1),
            plant_priority: Some(0),
            controller_priority: Some(0),
            spin_us: Some(200),
            lock_memory: Some(false),
            wake_early_us: Some(0),
            controller_wake_early_us: Some(-1),
            poll: Some(Poll::Spin),
        }
    }

    /// Fills every key this layout leaves unset from `d`, its wake-ups first kept within one
    /// period of `ts_s` ([`Layout::wake_early_within`]).
    pub(crate) fn fill(&mut self, d: Layout, ts_s: f64) {
        let d = d.wake_early_within(ts_s);
        self.plant_cpu = self.plant_cpu.or(d.plant_cpu);
        self.controller_cpu = self.controller_cpu.or(d.controller_cpu);
        self.supervisor_cpu = self.supervisor_cpu.or(d.supervisor_cpu);
        self.plant_priority = self.plant_priority.or(d.plant_priority);
        self.controller_priority = self.controller_priority.or(d.controller_priority);
        self.spin_us = self.spin_us.or(d.spin_us);
        self.lock_memory = self.lock_memory.or(d.lock_memory);
        self.wake_early_us = self.wake_early_us.or(d.wake_early_us);
        self.controller_wake_early_us =
            self.controller_wake_early_us.or(d.controller_wake_early_us);
        self.poll = self.poll.or(d.poll);
    }

    /// This layout with `wake_early_us` at most one period of `ts_s` (µs), so a default never
    /// fails the check of [`Layout::validate`] at a short period the user chose. A non-finite or
    /// out-of-range `ts_s` leaves it as is (the period's own check reports that).
    fn wake_early_within(mut self, ts_s: f64) -> Self {
        let period_us = ts_s * 1e6;
        if let Some(w) = self.wake_early_us
            && period_us.is_finite()
            && period_us >= 0.0
            && f64::from(w) > period_us
        {
            // Truncation is the point: the largest whole µs within the period.
            self.wake_early_us = Some(period_us as u32);
        }
        if let Some(w) = self.controller_wake_early_us
            && period_us.is_finite()
            && period_us >= 0.0
            && f64::from(w) > period_us
        {
            self.controller_wake_early_us = Some(period_us as i32);
        }
        self
    }

    /// This layout in real types. A key still missing (a layout built in code rather than read
    /// from a file, where every key is filled) takes the neutral value: not pinned, SCHED_OTHER,
    /// no polling, no mlockall, no early wake-up, the controller waiting for the notification,
    /// `spin`. A value validation rejects maps to the nearest meaning: a negative CPU is not
    /// pinned, a priority outside 1..=99 is SCHED_OTHER.
    pub fn resolve(&self) -> ResolvedLayout {
        let cpu = |v: Option<i32>| v.and_then(|c| usize::try_from(c).ok());
        ResolvedLayout {
            plant_cpu: cpu(self.plant_cpu),
            controller_cpu: cpu(self.controller_cpu),
            supervisor_cpu: cpu(self.supervisor_cpu),
            plant_priority: Priority::from_key(self.plant_priority),
            controller_priority: Priority::from_key(self.controller_priority),
            spin_us: self.spin_us.unwrap_or(0),
            lock_memory: self.lock_memory.unwrap_or(false),
            wake_early_us: self.wake_early_us.unwrap_or(0),
            controller_wake_early_us: self
                .controller_wake_early_us
                .and_then(|us| u32::try_from(us).ok()),
            poll: self.poll.unwrap_or_default(),
        }
    }
}

/// How a loop process is scheduled: the `*_priority` keys, where 0 means SCHED_OTHER.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum Priority {
    /// The kernel's ordinary time-sharing policy.
    #[default]
    Other,

    /// SCHED_FIFO at this priority, 1..=99.
    Fifo(u8),
}

impl Priority {
    /// The priority of a `*_priority` key: 1..=99 is SCHED_FIFO, anything else SCHED_OTHER.
    fn from_key(v: Option<i32>) -> Self {
        v.and_then(|p| u8::try_from(p).ok())
            .filter(|p| (1..=99).contains(p))
            .map_or(Priority::Other, Priority::Fifo)
    }

    /// The SCHED_FIFO priority, if any.
    pub fn fifo(self) -> Option<u8> {
        match self {
            Priority::Other => None,
            Priority::Fifo(p) => Some(p),
        }
    }

    /// The value of the config key: the SCHED_FIFO priority, 0 for SCHED_OTHER.
    pub fn key_value(self) -> u8 {
        self.fifo().unwrap_or(0)
    }
}

impl std::fmt::Display for Priority {
    /// `SCHED_OTHER` or `SCHED_FIFO 80`.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Priority::Other => f.write_str("SCHED_OTHER"),
            Priority::Fifo(p) => write!(f, "SCHED_FIFO {p}"),
        }
    }
}

/// One mode's layout with every key filled in and each value in its own type
/// ([`Layout::resolve`], [`crate::LoopMode::layout`]): what the loop processes and the supervisor
/// act on. The keys' meanings are documented on [`Layout`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ResolvedLayout {
    /// The plant process's CPU (None: not pinned).
    pub plant_cpu: Option<usize>,

    /// The controller process's CPU (None: not pinned).
    pub controller_cpu: Option<usize>,

    /// The supervisor's collector's CPU (None: not pinned).
    pub supervisor_cpu: Option<usize>,

    /// The plant's scheduling.
    pub plant_priority: Priority,

    /// The controller's scheduling.
    pub controller_priority: Priority,

    /// How long a process busy-polls for its peer's message before blocking, µs.
    pub spin_us: u32,

    /// mlockall in both loop processes.
    pub lock_memory: bool,

    /// Realtime: how long before each deadline the plant wakes and busy-waits, µs (0: none).
    pub wake_early_us: u32,

    /// Realtime: how long before each deadline the controller wakes and polls for the state, µs;
    /// None: it blocks on the wake-up event and the plant's notification wakes it.
    pub controller_wake_early_us: Option<u32>,

    /// What a process does between two looks for its peer's message.
    pub poll: Poll,
}

impl ResolvedLayout {
    /// [`ResolvedLayout::spin_us`] in ns.
    pub fn spin_ns(&self) -> u64 {
        u64::from(self.spin_us) * 1000
    }

    /// [`ResolvedLayout::wake_early_us`] in ns.
    pub fn wake_early_ns(&self) -> u64 {
        u64::from(self.wake_early_us) * 1000
    }

    /// The controller's lead before each deadline in realtime, ns; None: it waits for the
    /// notification instead.
    pub fn controller_lead_ns(&self) -> Option<u64> {
        self.controller_wake_early_us.map(|us| u64::from(us) * 1000)
    }
}

impl Layout {
    /// Checks one mode's layout; `section` names it in errors (`loop.realtime`, `loop.lockstep`),
    /// `ts_s` is the (already validated) control period, which bounds `wake_early_us`: waking more
    /// than a period before the deadline would wake before the previous tick.
    pub(crate) fn validate(&self, section: &str, ts_s: f64) -> Result<(), ConfigError> {
        for (key, cpu) in [
            (LAYOUT.plant_cpu, self.plant_cpu),
            (LAYOUT.controller_cpu, self.controller_cpu),
            (LAYOUT.supervisor_cpu, self.supervisor_cpu),
        ] {
            key.check_int_in(section, cpu.unwrap_or(-1).into())?;
        }
        for (key, priority) in [
            (LAYOUT.plant_priority, self.plant_priority),
            (LAYOUT.controller_priority, self.controller_priority),
        ] {
            key.check_int_in(section, priority.unwrap_or(0).into())?;
        }
        LAYOUT
            .spin_us
            .check_int_in(section, self.spin_us.unwrap_or(0).into())?;
        let wake = self.wake_early_us.unwrap_or(0);
        let period_us = ts_s * 1e6;
        if f64::from(wake) > period_us {
            return Err(range(
                &format!("{section}.wake_early_us"),
                wake,
                &format!("0 <= wake_early_us <= Ts = {period_us} us"),
            ));
        }
        let cwake = self.controller_wake_early_us.unwrap_or(-1);
        if cwake < -1 || f64::from(cwake) > period_us {
            return Err(range(
                &format!("{section}.controller_wake_early_us"),
                cwake,
                &format!(
                    "-1 (wait for the notification) or 0 <= controller_wake_early_us <= Ts = {period_us} us"
                ),
            ));
        }
        self.check_yield(section)
    }

    /// `poll = "yield"` hands the CPU over only to a peer of the same priority on the same CPU:
    /// anywhere else a yield returns at once, or never reaches a peer of lower priority, which
    /// would then starve behind the polling plant.
    fn check_yield(&self, section: &str) -> Result<(), ConfigError> {
        if self.poll != Some(Poll::Yield) {
            return Ok(());
        }
        let (pc, cc) = (
            self.plant_cpu.unwrap_or(-1),
            self.controller_cpu.unwrap_or(-1),
        );
        let (pp, cp) = (
            self.plant_priority.unwrap_or(0),
            self.controller_priority.unwrap_or(0),
        );
        if pc < 0 || pc != cc || pp != cp {
            return Err(range(
                &format!("{section}.poll"),
                "\"yield\"",
                &format!(
                    "\"yield\" needs plant_cpu = controller_cpu (pinned) and plant_priority = controller_priority; here plant_cpu {pc}, controller_cpu {cc}, plant_priority {pp}, controller_priority {cp} (or poll = \"spin\")"
                ),
            ));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::RunConfig;
    use crate::test_util::MIN;
    use std::path::Path;

    /// Every run config the repo ships loads and validates (the sweep and Slurm files have their
    /// own schema); `configs/soak-split.toml` is exactly the split-CPU layout docs/performance.md measures.
    #[test]
    fn shipped_run_configs_load_and_soak_split_is_the_split_layout() {
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../configs");
        let mut seen = 0;
        for dir in [root.clone(), root.join("paper")] {
            for e in std::fs::read_dir(&dir).unwrap().flatten() {
                let path = e.path();
                let text = std::fs::read_to_string(&path).unwrap_or_default();
                let sweep = text
                    .lines()
                    .any(|l| l.starts_with("[slurm]") || l.starts_with("scenarios = "));
                if path.extension().is_some_and(|x| x == "toml") && !sweep {
                    // from_toml_str validates too.
                    RunConfig::from_toml_str(&text, Some(&path))
                        .unwrap_or_else(|e| panic!("{}: {e}", path.display()));
                    seen += 1;
                }
            }
        }
        assert!(seen >= 9, "{seen} configs");
        let split = root.join("soak-split.toml");
        let c = RunConfig::from_toml_str(&std::fs::read_to_string(&split).unwrap(), Some(&split))
            .unwrap();
        assert_eq!(c.loop_.realtime, Layout::realtime_split_cpus());
        let one = root.join("soak-yield.toml");
        let c =
            RunConfig::from_toml_str(&std::fs::read_to_string(&one).unwrap(), Some(&one)).unwrap();
        assert_eq!(c.loop_.realtime, Layout::realtime_one_cpu_yield());
    }

    #[test]
    fn yielding_needs_plant_and_controller_on_one_cpu_at_one_priority() {
        let yield_with = |extra: &str| {
            RunConfig::from_toml_str(
                &format!("{MIN}[loop.realtime]\npoll = \"yield\"\n{extra}"),
                None,
            )
        };
        // The default layout has the plant above the controller: a yield would never reach it.
        let e = yield_with("").unwrap_err().to_string();
        assert!(
            e.contains("`loop.realtime.poll` = \"yield\"")
                && e.contains("plant_priority 80, controller_priority 70"),
            "{e}"
        );
        let e = yield_with("controller_priority = 80\ncontroller_cpu = 0\n")
            .unwrap_err()
            .to_string();
        assert!(e.contains("plant_cpu 1, controller_cpu 0"), "{e}");
        let e = yield_with("controller_priority = 80\nplant_cpu = -1\ncontroller_cpu = -1\n")
            .unwrap_err()
            .to_string();
        assert!(e.contains("plant_cpu -1, controller_cpu -1"), "{e}");
        let c = yield_with("controller_priority = 80\n").unwrap();
        assert_eq!(c.loop_.realtime.poll, Some(Poll::Yield));
        assert_eq!(
            RunConfig::from_toml_str(&c.to_toml_string(), None).unwrap(),
            c,
            "the resolved config round-trips with its poll"
        );
        let e = RunConfig::from_toml_str(&format!("{MIN}[loop.lockstep]\npoll = \"nap\"\n"), None)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("nap") && e.contains("spin") && e.contains("yield"),
            "{e}"
        );
        assert_eq!(Layout::realtime_default().poll, Some(Poll::Spin));
    }

    #[test]
    fn layouts_default_per_mode_and_validate() {
        let c = RunConfig::from_toml_str(&format!("{MIN}[loop.lockstep]\nspin_us = 5\n"), None)
            .unwrap();
        assert_eq!(c.loop_.realtime, Layout::realtime_default());
        assert_eq!(c.loop_.lockstep.spin_us, Some(5));
        assert_eq!(
            c.loop_.lockstep.plant_cpu,
            Layout::lockstep_default().plant_cpu
        );
        let e = RunConfig::from_toml_str(
            &format!("{MIN}[loop.realtime]\nplant_priority = 120\n"),
            None,
        )
        .unwrap_err();
        assert!(
            e.to_string()
                .contains("`loop.realtime.plant_priority` = 120"),
            "{e}"
        );
        let e = RunConfig::from_toml_str(&format!("{MIN}[loop]\ntorque_budget_us = 300\n"), None)
            .unwrap_err();
        assert!(
            e.to_string().contains("torque_budget_us` = 300")
                && e.to_string().contains("< Ts = 300"),
            "{e}"
        );
    }

    #[test]
    fn wake_early_us_is_bounded_by_the_period() {
        // Ts = 300 µs by default: a whole period early is allowed, more is not.
        for section in ["loop.realtime", "loop.lockstep"] {
            let c =
                RunConfig::from_toml_str(&format!("{MIN}[{section}]\nwake_early_us = 300\n"), None)
                    .unwrap();
            let layout = if section == "loop.realtime" {
                &c.loop_.realtime
            } else {
                &c.loop_.lockstep
            };
            assert_eq!(layout.wake_early_us, Some(300), "{section}");
            let e =
                RunConfig::from_toml_str(&format!("{MIN}[{section}]\nwake_early_us = 301\n"), None)
                    .unwrap_err();
            assert_eq!(
                e.to_string(),
                format!(
                    "config key `{section}.wake_early_us` = 301 is out of range: 0 <= wake_early_us <= Ts = 300 us"
                )
            );
        }
        // The bound follows the period.
        let e = RunConfig::from_toml_str(
            &format!("{MIN}[loop]\nts_s = 1e-3\ntorque_budget_us = 500\n[loop.realtime]\nwake_early_us = 1001\n"),
            None,
        )
        .unwrap_err();
        assert!(e.to_string().contains("<= Ts = 1000 us"), "{e}");
    }

    #[test]
    fn default_wake_early_us_fits_a_short_period() {
        // The realtime default (80 µs) is capped at a shorter period instead of rejected.
        let c = RunConfig::from_toml_str(
            &format!("{MIN}[loop]\nts_s = 5e-5\ntorque_budget_us = 20\n"),
            None,
        )
        .unwrap();
        assert_eq!(c.loop_.realtime.wake_early_us, Some(50));
        assert_eq!(c.loop_.realtime.controller_wake_early_us, Some(50));
        assert_eq!(c.loop_.lockstep.wake_early_us, Some(0));
        let again = RunConfig::from_toml_str(&c.to_toml_string(), None).unwrap();
        assert_eq!(c, again);
    }

    #[test]
    fn controller_wake_early_us_is_minus_one_or_within_the_period() {
        for (v, ok) in [
            ("-1", true),
            ("0", true),
            ("300", true),
            ("301", false),
            ("-2", false),
        ] {
            let r = RunConfig::from_toml_str(
                &format!("{MIN}[loop.realtime]\ncontroller_wake_early_us = {v}\n"),
                None,
            );
            match (r, ok) {
                (Ok(c), true) => assert_eq!(
                    c.loop_.realtime.resolve().controller_lead_ns(),
                    v.parse::<u64>().ok().map(|us| us * 1000)
                ),
                (Err(e), false) => assert_eq!(
                    e.to_string(),
                    format!(
                        "config key `loop.realtime.controller_wake_early_us` = {v} is out of range: -1 (wait for the notification) or 0 <= controller_wake_early_us <= Ts = 300 us"
                    )
                ),
                (r, _) => panic!("{v}: {r:?}"),
            }
        }
    }

    #[test]
    fn the_resolved_layout_turns_sentinels_into_types() {
        assert_eq!(
            Layout::realtime_default().resolve(),
            ResolvedLayout {
                plant_cpu: Some(1),
                controller_cpu: Some(1),
                supervisor_cpu: Some(0),
                plant_priority: Priority::Fifo(80),
                controller_priority: Priority::Fifo(70),
                spin_us: 0,
                lock_memory: true,
                wake_early_us: 80,
                controller_wake_early_us: Some(50),
                poll: Poll::Spin,
            }
        );
        // −1 is "not pinned" and "wait for the notification", 0 is SCHED_OTHER.
        let ls = Layout::lockstep_default().resolve();
        assert_eq!(ls.supervisor_cpu, None);
        assert_eq!(ls.plant_priority, Priority::Other);
        assert_eq!(ls.controller_wake_early_us, None);
        assert_eq!((ls.spin_ns(), ls.controller_lead_ns()), (200_000, None));
        // What the modes hand out is the file's layout, resolved.
        let c = RunConfig::from_toml_str(
            &format!(
                "{MIN}[loop.lockstep]
plant_cpu = -1
"
            ),
            None,
        )
        .unwrap();
        let lock = crate::LoopMode::Lockstep.layout(&c).unwrap();
        assert_eq!(lock.plant_cpu, None);
        assert_eq!(lock, c.loop_.lockstep.resolve());
        assert_eq!(crate::LoopMode::Inproc.layout(&c), None);
        // A layout built in code with keys missing gets the neutral values.
        let none = Layout::default().resolve();
        assert_eq!(
            (none.plant_cpu, none.plant_priority),
            (None, Priority::Other)
        );
        assert_eq!((none.lock_memory, none.poll), (false, Poll::Spin));
    }
}
