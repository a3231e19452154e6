//! Which thread (or interrupt) ran on which CPU over a span: the bars of `<law>.worst-miss.svg`.
//! Pure.

use crate::event::{Event, Kind};
use std::collections::BTreeMap;

/// What one CPU ran over [`from_ns`, `to_ns`).
#[derive(Clone, Debug, PartialEq)]
pub struct Segment {
    pub cpu: usize,
    pub from_ns: u64,
    pub to_ns: u64,
    /// A command name with its pid (`burner 4242`), `irq: <name>`, `softirq: <NAME>` or `idle`.
    pub label: String,
    /// A loop thread ran.
    pub is_loop: bool,
}

/// The segments of `cpus` over [`t0`, `t1`] from `events` (in time order, from before `t0` so
/// each CPU's state at `t0` is known). `pids`: the loop threads.
pub fn segments(
    events: impl IntoIterator<Item = Event>,
    cpus: &[usize],
    pids: &[i32],
    (t0, t1): (u64, u64),
) -> Vec<Segment> {
    #[derive(Clone, Default)]
    struct State {
        label: Option<(String, bool)>,
        irq: Option<String>,
        soft: Option<String>,
        since: u64,
    }
    let shown = |s: &State| -> Option<(String, bool)> {
        if let Some(i) = &s.irq {
            Some((format!("irq: {i}"), false))
        } else if let Some(n) = &s.soft {
            Some((format!("softirq: {n}"), false))
        } else {
            s.label.clone()
        }
    };
    let mut state: BTreeMap<usize, State> = cpus.iter().map(|&c| (c, State::default())).collect();
    let mut out = Vec::new();
    let close = |cpu: usize, s: &State, t: u64, out: &mut Vec<Segment>| {
        let (a, b) = (s.since.max(t0), t.min(t1));
        if let (Some((label, is_loop)), true) = (shown(s), b > a) {
            out.push(Segment {
                cpu,
                from_ns: a,
                to_ns: b,
                label,
                is_loop,
            });
        }
    };
    for e in events {
        if e.t_ns > t1 {
            break;
        }
        let Some(s) = state.get_mut(&e.cpu) else {
            continue;
        };
        let before = shown(s);
        let mut next = s.clone();
        match &e.kind {
            Kind::Switch { next: th, .. } => {
                next.label = Some(if th.is_idle() {
                    ("idle".into(), false)
                } else {
                    (format!("{} {}", th.comm, th.pid), pids.contains(&th.pid))
                });
            }
            Kind::IrqEntry { name, .. } => next.irq = Some(name.clone()),
            Kind::IrqExit => next.irq = None,
            Kind::SoftirqEntry { name } => next.soft = Some(name.clone()),
            Kind::SoftirqExit => next.soft = None,
            Kind::Lost { .. } => next = State::default(),
            Kind::Waking { .. } | Kind::Steal { .. } => continue,
        }
        if shown(&next) != before {
            close(e.cpu, s, e.t_ns, &mut out);
            next.since = e.t_ns;
        }
        *s = next;
    }
    for (&cpu, s) in &state {
        close(cpu, s, t1, &mut out);
    }
    out.sort_by_key(|s| (s.cpu, s.from_ns));
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::event::Thread;

    #[test]
    fn a_burst_between_two_loop_runs_is_three_segments_and_an_irq_cuts_one() {
        let sw = |t: u64, pid: i32, comm: &str| Event {
            t_ns: t,
            cpu: 1,
            kind: Kind::Switch {
                prev_pid: -1,
                prev_runnable: false,
                next: Thread {
                    pid,
                    comm: comm.into(),
                    prio: 29,
                },
            },
        };
        let ev = vec![
            sw(0, 100, "ctl"),
            sw(50, 7, "burner"),
            Event {
                t_ns: 60,
                cpu: 1,
                kind: Kind::IrqEntry {
                    irq: 1,
                    name: "eth0".into(),
                },
            },
            Event {
                t_ns: 70,
                cpu: 1,
                kind: Kind::IrqExit,
            },
            sw(90, 100, "ctl"),
            sw(200, 0, "swapper/1"),
        ];
        let s = segments(ev, &[1], &[100], (10, 150));
        let got: Vec<_> = s
            .iter()
            .map(|s| (s.from_ns, s.to_ns, s.label.as_str(), s.is_loop))
            .collect();
        assert_eq!(
            got,
            [
                (10, 50, "ctl 100", true),
                (50, 60, "burner 7", false),
                (60, 70, "irq: eth0", false),
                (70, 90, "burner 7", false),
                (90, 150, "ctl 100", true),
            ]
        );
    }
}
