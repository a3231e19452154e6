//! What `top --foxglove` serves: the observer's messages joined by tick and recorded as a run
//! records them (the same [`Recorder`] and the same rows as `<law>.mcap`), onto any
//! [`Bus`]: the live server, or a test's memory.
//!
//! It is a view, not the record: `top` sees the loop through the spare observer slots, which
//! lose their oldest samples when `top` falls behind (a tick seen without its state is counted
//! lost, not drawn); the run's own files stay the record.

use anyhow::Result;
use deltaloop_config::Law;
use deltaloop_config::RemoteSide;
use deltaloop_model::Vec3;
use deltaloop_report::mcap::{Bus, ERROR, INFO, Live};
use deltaloop_study::Study;
use deltaloop_study::record::{Recorder, TickRecord, TickSink};
use deltaloop_study::reference::RefRow;
use deltaloop_timing::{Seen, timing_cells};
use deltaloop_transport::wire::{StateMsg, TelemetryMsg, TorqueMsg};
use std::collections::BTreeMap;

/// A tick is joined this many ticks after the newest state (a reply or the telemetry may come
/// a few ticks late; 16 ticks is 4.8 ms at 3.3 kHz).
pub const JOIN_LAG: u64 = 16;
/// Ticks waiting to be joined at most (older ones are dropped: `top` fell far behind).
const MAX_PENDING: usize = 8_192;

/// The recorder's sink: the law's channels on the bus; the first error is kept.
struct Feed<B: Bus> {
    live: Live<B>,
    error: Option<anyhow::Error>,
}

impl<B: Bus> TickSink for Feed<B> {
    fn take(&mut self, r: &TickRecord, row: &RefRow, n_true: Option<Vec3>) {
        if self.error.is_none()
            && let Err(e) = self.live.take(r, row, n_true)
        {
            self.error = Some(e);
        }
    }
}

/// The observer's messages, joined and relayed.
pub struct Relay<'a, B: Bus> {
    study: &'a Study,
    rec: Recorder<'a, Feed<B>>,
    pending: BTreeMap<u64, Seen>,
    link: Option<RemoteSide>,
    newest_state: Option<u64>,
    /// The next tick to join (None before the first state).
    next: Option<u64>,
    /// The recorder's divergence rule stopped the rows.
    stopped: bool,
}

impl<'a, B: Bus> Relay<'a, B> {
    /// `law` of `study` onto `bus`; the robot drawn every `scene_every` ticks.
    pub fn new(bus: B, study: &'a Study, law: Law, scene_every: u64) -> Result<Self> {
        let live = Live::over(bus, study, law, scene_every)?;
        let feed = Feed { live, error: None };
        Ok(Self {
            study,
            rec: Recorder::new(law, &study.reference, study.params.m_bar, feed),
            pending: BTreeMap::new(),
            link: deltaloop_report::link::across(&study.config),
            newest_state: None,
            next: None,
            stopped: false,
        })
    }

    fn slot(&mut self, k: u64) -> Option<&mut Seen> {
        if self.next.is_some_and(|n| k < n) {
            return None; // already joined: too late for this view
        }
        if self.pending.len() >= MAX_PENDING && !self.pending.contains_key(&k) {
            self.pending.pop_first();
        }
        Some(self.pending.entry(k).or_insert(Seen {
            k,
            ..Seen::default()
        }))
    }

    pub fn state(&mut self, s: &StateMsg) {
        self.newest_state = Some(self.newest_state.map_or(s.tick, |n| n.max(s.tick)));
        self.next.get_or_insert(s.tick);
        if let Some(seen) = self.slot(s.tick) {
            seen.state = Some(*s);
        }
    }

    pub fn torque(&mut self, t: &TorqueMsg) {
        if let Some(seen) = self.slot(t.tick) {
            seen.torque.get_or_insert(*t);
        }
    }

    pub fn telemetry(&mut self, m: &TelemetryMsg) {
        if let Some(seen) = self.slot(m.tick) {
            seen.tel = Some(*m);
        }
    }

    /// Joins every tick [`JOIN_LAG`] behind the newest state (all of them if `all`: the run has
    /// ended), in tick order. Returns the bus's first error.
    pub fn flush(&mut self, all: bool) -> Result<()> {
        let (Some(newest), Some(mut next)) = (self.newest_state, self.next) else {
            return Ok(());
        };
        let upto = if all {
            self.pending.last_key_value().map_or(newest, |(k, _)| *k)
        } else {
            newest.saturating_sub(JOIN_LAG)
        };
        while next <= upto {
            let seen = self.pending.remove(&next).unwrap_or(Seen {
                k: next,
                ..Seen::default()
            });
            self.join(&seen)?;
            next += 1;
        }
        self.next = Some(next);
        self.error()
    }

    fn join(&mut self, seen: &Seen) -> Result<()> {
        if let Some(cells) = timing_cells(seen, self.link) {
            self.rec.sink_mut().live.timing(&cells)?;
        }
        if self.stopped || seen.k > self.study.reference.n as u64 {
            return Ok(());
        }
        match seen.state {
            Some(state) => {
                if !self.rec.tick(&state, seen.torque.as_ref()) {
                    self.stopped = true;
                }
                self.rec.applied(seen.tel.as_ref());
            }
            None => self.rec.lost(seen.k),
        }
        Ok(())
    }

    fn error(&mut self) -> Result<()> {
        match self.rec.sink_mut().error.take() {
            Some(e) => Err(e),
            None => Ok(()),
        }
    }

    /// The run ended (`ok`: completed): joins what is left, closes the open ticks and says how
    /// it ended on the events channel.
    pub fn finish(mut self, ok: bool, how: &str) -> Result<B> {
        self.flush(true)?;
        let tick = self.next.unwrap_or(0);
        let (_, mut feed) = self.rec.finish(None);
        if let Some(e) = feed.error.take() {
            return Err(e);
        }
        feed.live
            .event(tick, if ok { INFO } else { ERROR }, how.to_string())?;
        Ok(feed.live.into_bus())
    }

    /// The bus the rows go to.
    pub fn bus(&self) -> &B {
        self.rec.sink().live.bus()
    }

    /// Draws the reference path again (for clients that joined late).
    pub fn reference_again(&mut self) -> Result<()> {
        self.rec.sink_mut().live.reference_again(self.study)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use deltaloop_config::RunConfig;
    use deltaloop_transport::wire;
    use serde_json::Value;

    /// A bus that keeps every message: (topic, t_ns, bytes).
    #[derive(Default)]
    struct Memory {
        topics: Vec<String>,
        got: Vec<(String, u64, Vec<u8>)>,
    }

    impl Bus for Memory {
        fn schema(&mut self, _: &'static str, _: &str, _: &str) -> Result<u16> {
            Ok(0)
        }
        fn channel(&mut self, _: u16, topic: &str, _: &str) -> Result<u16> {
            self.topics.push(topic.into());
            Ok(u16::try_from(self.topics.len() - 1)?)
        }
        fn write(&mut self, channel: u16, t_ns: u64, data: &[u8]) -> Result<()> {
            let topic = self.topics[usize::from(channel)].clone();
            self.got.push((topic, t_ns, data.to_vec()));
            Ok(())
        }
    }

    impl Memory {
        fn on(&self, topic: &str) -> Vec<(u64, &[u8])> {
            let got = self.got.iter().filter(|(t, _, _)| t == topic);
            got.map(|(_, t, d)| (*t, d.as_slice())).collect()
        }
    }

    fn study() -> Study {
        let cfg =
            RunConfig::from_toml_str("name = \"t\"\n[scenario]\npath = \"s1\"\n", None).unwrap();
        Study::new(cfg).unwrap()
    }

    fn state(st: &Study, k: u64) -> StateMsg {
        let q = st.reference.row(k as usize).joint.q;
        let q = [q[0] + 1e-4 * k as f64, q[1], q[2]];
        StateMsg {
            tick: k,
            q,
            // trace.csv's q is the true angle (the measured one is what the controller saw).
            q_true: q,
            t_deadline_ns: 1_000 + k * 300_000,
            t_publish_ns: 2_000 + k * 300_000,
            ..StateMsg::default()
        }
    }

    /// The view joins what arrives out of order by tick, draws every tick it saw whole with the
    /// state's own numbers, counts a tick without a state as lost (no row), and ends with the
    /// run's end on the events channel.
    #[test]
    fn ticks_arriving_out_of_order_are_joined_and_a_missing_state_is_not_drawn() {
        let st = study();
        let mut r = Relay::new(Memory::default(), &st, Law::Tdc, 10).unwrap();
        let (first, last, hole) = (100u64, 199u64, 150u64);
        for k in first..=last {
            let mut tel = TelemetryMsg {
                tick: k,
                t_torque_rx_ns: 5_000 + k * 300_000,
                ..TelemetryMsg::default()
            };
            if k == 120 {
                tel.flags = wire::TEL_MISSED;
            }
            // Telemetry first, the reply next, the state last: the order a slow observer sees.
            r.telemetry(&tel);
            if k != 120 {
                r.torque(&TorqueMsg {
                    tick: k,
                    tau: [k as f64, 0.0, 0.0],
                    ..TorqueMsg::default()
                });
            }
            if k != hole {
                r.state(&state(&st, k));
            }
            r.flush(false).unwrap();
        }
        let mem = r.finish(true, "run completed at tick 200").unwrap();
        let joints = mem.on("/tdc/joint_states");
        let ticks: Vec<u64> = joints.iter().map(|(t, _)| t / 300_000).collect();
        let want: Vec<u64> = (first..=last).filter(|&k| k != hole).collect();
        assert_eq!(ticks, want, "one joint state per tick seen whole, in order");
        for (t, data) in &joints {
            let k = t / 300_000;
            let q0 = state(&st, k).q[0];
            // The CDR message carries q as little-endian doubles; the state's first angle is in it.
            let bits = q0.to_le_bytes();
            assert!(
                data.windows(8).any(|w| w == bits),
                "tick {k}: q₁ = {q0:e} not in its joint state bit for bit"
            );
        }
        let control: Vec<Value> = mem
            .on("/tdc/control")
            .iter()
            .map(|(_, d)| serde_json::from_slice(d).unwrap())
            .collect();
        let reply = |k: u64| {
            control.iter().find(|c| c["k"] == k).unwrap()["reply"]
                .as_str()
                .unwrap()
                .to_string()
        };
        assert_eq!(reply(110), "applied");
        assert_eq!(reply(120), "missed");
        assert_eq!(mem.on("/tdc/timing").len(), (last - first + 1) as usize);
        let scenes = mem.on("/tdc/scene");
        assert!(scenes.iter().all(|(t, _)| (t / 300_000) % 10 == 0));
        assert_eq!(
            scenes.len(),
            9,
            "every 10th tick from 100 to 190 but the hole, 150"
        );
        let events: Vec<String> = mem
            .on("/tdc/events")
            .iter()
            .map(|(_, d)| serde_json::from_slice::<Value>(d).unwrap()["message"].to_string())
            .collect();
        assert!(
            events.iter().any(|e| e.contains("tick 120: reply missed")),
            "{events:?}"
        );
        assert!(
            events.last().unwrap().contains("run completed"),
            "{events:?}"
        );
    }
}
