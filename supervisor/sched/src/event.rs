//! The kernel's scheduling events as tracefs prints them (`trace_pipe`, `trace_clock = mono`),
//! parsed into [`Event`]s. Pure: a line in, an event out.

/// One kernel event on one CPU. `t_ns`: CLOCK_MONOTONIC, ns (tracefs prints µs).
#[derive(Clone, Debug, PartialEq)]
pub struct Event {
    pub t_ns: u64,
    pub cpu: usize,
    pub kind: Kind,
}

/// What happened.
#[derive(Clone, Debug, PartialEq)]
pub enum Kind {
    /// The CPU went from `prev_pid` to `next`. `prev_runnable`: the previous thread stays
    /// runnable (preempted, state `R`), rather than going to sleep.
    Switch {
        prev_pid: i32,
        prev_runnable: bool,
        next: Thread,
    },
    /// Thread `pid` was woken (made runnable), to run on `target_cpu`.
    Waking {
        pid: i32,
        target_cpu: usize,
    },
    /// A hard interrupt handler began (`name` as /proc/interrupts calls it).
    IrqEntry {
        irq: u32,
        name: String,
    },
    IrqExit,
    /// A softirq began: `NET_RX`, `TIMER`, `SCHED`, `RCU`, …
    SoftirqEntry {
        name: String,
    },
    SoftirqExit,
    /// The CPU's steal clock (/proc/stat, jiffies) as the recorder sampled it: time the
    /// hypervisor ran something else while this virtual CPU had work.
    Steal {
        jiffies: u64,
    },
    /// The ring buffer overwrote events the reader had not taken yet.
    Lost {
        count: u64,
    },
}

/// A thread as the kernel names it.
#[derive(Clone, Debug, PartialEq, Eq, Hash)]
pub struct Thread {
    pub pid: i32,
    /// Its command name (at most 15 bytes).
    pub comm: String,
    /// The kernel's priority: 0..=99 real-time (SCHED_FIFO/RR priority 99 − prio), 100..=139
    /// normal (nice prio − 120).
    pub prio: i32,
}

impl Thread {
    /// The idle task (pid 0) runs when the CPU has nothing else to run.
    pub fn is_idle(&self) -> bool {
        self.pid == 0
    }

    /// The priority as `chrt` and `nice` name it: `FIFO 75`, `nice 0`.
    pub fn policy(&self) -> String {
        if self.prio < 100 {
            format!("FIFO {}", 99 - self.prio)
        } else {
            format!("nice {}", self.prio - 120)
        }
    }
}

/// The tracefs event names this crate enables, as `<system>/<event>`.
pub const EVENTS: [&str; 6] = [
    "sched/sched_switch",
    "sched/sched_waking",
    "irq/irq_handler_entry",
    "irq/irq_handler_exit",
    "irq/softirq_entry",
    "irq/softirq_exit",
];

/// One line of `trace_pipe`, or None for a line of another event or shape. The recorder's own
/// lines (`steal cpu=N jiffies=J t=T`) and tracefs' `CPU:N [LOST K EVENTS]` parse too.
pub fn parse(line: &str) -> Option<Event> {
    if let Some(rest) = line.strip_prefix("steal ") {
        let cpu = num(rest, "cpu=")?;
        return Some(Event {
            t_ns: num(rest, "t=")?,
            cpu,
            kind: Kind::Steal {
                jiffies: num(rest, "jiffies=")?,
            },
        });
    }
    if let Some(rest) = line.trim_start().strip_prefix("CPU:") {
        // "CPU:1 [LOST 12 EVENTS]": no time; the analysis takes it at the last event's.
        let (cpu, rest) = rest.split_once(' ')?;
        let count = rest
            .strip_prefix("[LOST ")?
            .split(' ')
            .next()?
            .parse()
            .ok()?;
        return Some(Event {
            t_ns: 0,
            cpu: cpu.parse().ok()?,
            kind: Kind::Lost { count },
        });
    }
    // "<comm>-<pid> [CPU] flags SECS.USECS: <event>: <fields>"; a comm may hold spaces and
    // brackets, so the header is read from its right end.
    let (head, event, fields) = [
        "sched_switch",
        "sched_waking",
        "irq_handler_entry",
        "irq_handler_exit",
        "softirq_entry",
        "softirq_exit",
    ]
    .iter()
    .find_map(|name| {
        let at = line.find(&format!(": {name}: "))?;
        Some((&line[..at], *name, &line[at + name.len() + 4..]))
    })?;
    let mut words = head.rsplit(' ').filter(|w| !w.is_empty());
    let t_ns = micros_to_ns(words.next()?)?;
    let cpu = words
        .find(|w| w.starts_with('[') && w.ends_with(']'))?
        .trim_matches(['[', ']'])
        .parse()
        .ok()?;
    let kind = match event {
        "sched_switch" => {
            let state = text(fields, "prev_state=", " ==> ")?;
            Kind::Switch {
                prev_pid: num(fields, " prev_pid=")?,
                prev_runnable: state.starts_with('R'),
                next: Thread {
                    pid: num(fields, " next_pid=")?,
                    comm: text(fields, "next_comm=", " next_pid=")?.to_string(),
                    prio: num(fields, " next_prio=")?,
                },
            }
        }
        "sched_waking" => Kind::Waking {
            pid: num(fields, " pid=")?,
            target_cpu: num(fields, "target_cpu=")?,
        },
        "irq_handler_entry" => Kind::IrqEntry {
            irq: num(fields, "irq=")?,
            name: fields.split_once("name=")?.1.trim().to_string(),
        },
        "irq_handler_exit" => Kind::IrqExit,
        "softirq_entry" => Kind::SoftirqEntry {
            name: text(fields, "[action=", "]")?.to_string(),
        },
        _ => Kind::SoftirqExit,
    };
    Some(Event { t_ns, cpu, kind })
}

/// "46792.632256" (s.µs) → ns.
fn micros_to_ns(s: &str) -> Option<u64> {
    let s = s.trim_end_matches(':');
    let (sec, us) = s.split_once('.')?;
    let us: u64 = format!("{us:0<6}").get(..6)?.parse().ok()?;
    Some(sec.parse::<u64>().ok()?.checked_mul(1_000_000_000)? + us * 1000)
}

/// The text after `key` up to `end` (or the end of `s`).
fn text<'a>(s: &'a str, key: &str, end: &str) -> Option<&'a str> {
    let rest = &s[s.find(key)? + key.len()..];
    Some(rest.find(end).map_or(rest, |e| &rest[..e]))
}

/// The number after `key` (up to the next space).
fn num<T: std::str::FromStr>(s: &str, key: &str) -> Option<T> {
    text(s, key, " ")?.trim().parse().ok()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Lines as this machine's kernel (6.18) printed them.
    #[test]
    fn the_kernels_lines_parse() {
        let e = parse("           sleep-14496   [001] d..2. 46792.632256: sched_switch: prev_comm=sleep prev_pid=14496 prev_prio=120 prev_state=S ==> next_comm=swapper/1 next_pid=0 next_prio=120").unwrap();
        assert_eq!(e.t_ns, 46_792_632_256_000);
        assert_eq!(e.cpu, 1);
        assert_eq!(
            e.kind,
            Kind::Switch {
                prev_pid: 14496,
                prev_runnable: false,
                next: Thread {
                    pid: 0,
                    comm: "swapper/1".into(),
                    prio: 120
                }
            }
        );
        let e = parse("          <idle>-0       [001] d.s3. 46792.636054: sched_waking: comm=rcu_preempt pid=15 prio=120 target_cpu=001").unwrap();
        assert_eq!(
            e.kind,
            Kind::Waking {
                pid: 15,
                target_cpu: 1
            }
        );
        let e = parse(
            "          <idle>-0       [001] ..s1. 46792.640057: softirq_entry: vec=9 [action=RCU]",
        )
        .unwrap();
        assert_eq!(e.kind, Kind::SoftirqEntry { name: "RCU".into() });
        let e = parse("          <idle>-0       [000] d.h1. 46792.1: irq_handler_entry: irq=24 name=virtio0-input.0").unwrap();
        assert_eq!(e.t_ns, 46_792_100_000_000);
        assert_eq!(
            e.kind,
            Kind::IrqEntry {
                irq: 24,
                name: "virtio0-input.0".into()
            }
        );
    }

    /// A command name with spaces, brackets and a dash, preempted (state R+).
    #[test]
    fn odd_command_names_and_a_preempted_thread() {
        let e = parse(" Web [Co]-nt-ent-77 [000] d..2. 10.000001: sched_switch: prev_comm=Web [Co]-nt-ent prev_pid=77 prev_prio=120 prev_state=R+ ==> next_comm=burn me next_pid=9 next_prio=24").unwrap();
        assert_eq!(e.cpu, 0);
        let Kind::Switch {
            prev_pid,
            prev_runnable,
            next,
        } = e.kind
        else {
            panic!("{e:?}")
        };
        assert_eq!((prev_pid, prev_runnable), (77, true));
        assert_eq!(next.comm, "burn me");
        assert_eq!(next.policy(), "FIFO 75");
    }

    #[test]
    fn the_recorders_own_lines_and_lost_events_parse_and_others_do_not() {
        assert_eq!(
            parse("steal cpu=1 jiffies=42 t=5000").unwrap(),
            Event {
                t_ns: 5000,
                cpu: 1,
                kind: Kind::Steal { jiffies: 42 }
            }
        );
        assert_eq!(
            parse("CPU:1 [LOST 12 EVENTS]").unwrap().kind,
            Kind::Lost { count: 12 }
        );
        assert!(
            parse("  bash-1 [000] .... 1.000000: sched_process_exec: filename=/bin/ls").is_none()
        );
        assert!(parse("").is_none());
        assert!(parse("garbage: sched_switch: ").is_none());
    }
}
