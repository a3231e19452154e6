//! One tick's messages from its trace row: where the columns are, the row parsed, and the JSON
//! of its `control` and `timing` messages. Both are written as the run records, one each a tick,
//! so they are serialised straight from the row (a `serde_json::Value` map per message cost a
//! few dozen allocations a tick), with their keys in the order serde_json's maps sort them.

use super::{Bus, Channels, INFO, WARNING};
use crate::trace;
use anyhow::Result;
use deltaloop_mcap::cdr;
use deltaloop_mcap::scene::Painter;
use deltaloop_model::Vec3;
use serde::Serialize;
use serde::ser::{SerializeMap, Serializer};
use std::ops::RangeInclusive;

/// The per-joint groups a `JointState` carries (not repeated in the control message).
const JOINT_STATE: [&str; 3] = ["q", "qdot", "tau_applied"];

/// A field of the control message.
#[derive(Clone, Copy)]
enum Field {
    K,
    Ts,
    /// The per-joint group at this index of [`Row::joints`].
    Group(usize),
    Reply,
    Drives,
    Arrival,
}

impl Field {
    fn name(self, joints: &[(&'static str, [usize; 3])]) -> &'static str {
        match self {
            Field::K => "k",
            Field::Ts => "t_s",
            Field::Group(i) => joints[i].0,
            Field::Reply => "reply",
            Field::Drives => "drives",
            Field::Arrival => "arrival_ns",
        }
    }
}

/// Where each trace column is, found by name.
pub(super) struct Columns {
    pub(super) law: usize,
    k: usize,
    /// `(name, columns of joints 1, 2, 3)` of every per-joint group, in trace order.
    joints: Vec<(&'static str, [usize; 3])>,
    reply: usize,
    drives: usize,
    arrival: usize,
    /// The control message's fields in the order they are written (by name, as JSON maps of
    /// serde_json write them).
    control: Vec<Field>,
}

impl Columns {
    pub(super) fn find(col: &dyn Fn(&str) -> Result<usize>) -> Result<Self> {
        let joints: Vec<_> = trace::COLUMNS
            .iter()
            .filter(|c| c.per_joint)
            .map(|c| {
                let at = |j: usize| col(&format!("{}_{j}", c.name));
                Ok((c.name, [at(1)?, at(2)?, at(3)?]))
            })
            .collect::<Result<_>>()?;
        let mut control = vec![
            Field::K,
            Field::Ts,
            Field::Reply,
            Field::Drives,
            Field::Arrival,
        ];
        control.extend(
            (0..joints.len())
                .filter(|&i| !JOINT_STATE.contains(&joints[i].0))
                .map(Field::Group),
        );
        control.sort_by_key(|f| f.name(&joints));
        Ok(Self {
            control,
            law: col(trace::LAW.name)?,
            k: col(trace::K.name)?,
            joints,
            reply: col(trace::REPLY.name)?,
            drives: col(trace::DRIVES.name)?,
            arrival: col(trace::ARRIVAL.name)?,
        })
    }
}

/// One trace row, parsed.
pub(super) struct Row {
    pub(super) k: u64,
    /// Every per-joint group: its name and three values (None: an empty cell).
    joints: Vec<(&'static str, [Option<f64>; 3])>,
    reply: String,
    drives: String,
    arrival_ns: Option<u64>,
}

impl Row {
    /// The row whose field `i` is `cell(i)`, every cell checked as its column says (an error
    /// names the column, the value and what is allowed); an applied reply's arrival within
    /// `arrivals`, ns ([`trace::arrivals`]).
    pub(super) fn parse<'a>(
        cell: &dyn Fn(usize) -> &'a str,
        c: &Columns,
        arrivals: &RangeInclusive<u64>,
    ) -> Result<Self> {
        let k = trace::tick_cell(cell(c.k))?;
        let joints = c
            .joints
            .iter()
            .map(|&(name, at)| {
                let v = |j: usize| trace::number_cell(name, Some(j + 1), cell(at[j]));
                Ok((name, [v(0)?, v(1)?, v(2)?]))
            })
            .collect::<Result<_>>()?;
        let (reply, drives) = (cell(c.reply), cell(c.drives));
        let fate = trace::reply_cell(reply)?;
        trace::drives_cell(drives)?;
        let arrival_ns = trace::arrival_cell(cell(c.arrival), fate, arrivals)?;
        Ok(Self {
            k,
            joints,
            reply: reply.into(),
            drives: drives.into(),
            arrival_ns,
        })
    }

    fn group(&self, name: &str) -> [Option<f64>; 3] {
        self.joints
            .iter()
            .find(|(n, _)| *n == name)
            .map_or([None; 3], |(_, v)| *v)
    }
}

/// Tick `row`'s control message: the trace row but for the joint state, with the time `t_s`.
struct Control<'a> {
    row: &'a Row,
    cols: &'a Columns,
    /// t = k·Ts, s.
    t_s: f64,
}

impl Serialize for Control<'_> {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        let (r, cols) = (self.row, self.cols);
        let mut m = s.serialize_map(Some(cols.control.len()))?;
        for &f in &cols.control {
            let key = f.name(&cols.joints);
            match f {
                Field::K => m.serialize_entry(key, &r.k)?,
                Field::Ts => m.serialize_entry(key, &self.t_s)?,
                Field::Group(i) => m.serialize_entry(key, &r.joints[i].1)?,
                Field::Reply => m.serialize_entry(key, &r.reply)?,
                Field::Drives => m.serialize_entry(key, &r.drives)?,
                Field::Arrival => m.serialize_entry(key, &r.arrival_ns)?,
            }
        }
        m.end()
    }
}

/// A timing row's message: its cells by column name (null: not seen) and the round trip
/// `round_trip_ns` (torque received − state published, ns).
struct Timing<'a> {
    cells: &'a [(&'a str, Option<u64>)],
    /// The cells' indices by name, `cells.len()` standing for the round trip.
    order: &'a [usize],
}

/// The order [`Timing`] writes `names` (and the round trip) in.
pub(super) fn timing_order<'a>(names: impl Iterator<Item = &'a str>) -> Vec<usize> {
    let names: Vec<&str> = names.chain(["round_trip_ns"]).collect();
    let mut order: Vec<usize> = (0..names.len()).collect();
    order.sort_by_key(|&i| names[i]);
    order
}

impl<'a> Timing<'a> {
    /// The message of `cells`, keys in `order` ([`timing_order`] of their names); with its tick.
    fn new(cells: &'a [(&'a str, Option<u64>)], order: &'a [usize]) -> (u64, Self) {
        let k = Self::cell(cells, "k").unwrap_or(0);
        (k, Timing { cells, order })
    }

    fn cell(cells: &[(&str, Option<u64>)], name: &str) -> Option<u64> {
        cells.iter().find(|c| c.0 == name).and_then(|c| c.1)
    }
}

/// Writes the timing message of `cells` (keys in `order`, [`timing_order`] of their names) on
/// `ch`'s timing channel at its tick.
pub(super) fn write_timing(
    out: &mut impl Bus,
    ch: &Channels,
    ts_ns: u64,
    cells: &[(&str, Option<u64>)],
    order: &[usize],
) -> Result<()> {
    let (k, m) = Timing::new(cells, order);
    out.json(ch.timing, k * ts_ns, &m)
}

impl Serialize for Timing<'_> {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        let rtt = Self::cell(self.cells, "torque_rx_ns")
            .zip(Self::cell(self.cells, "state_pub_ns"))
            .map(|(a, b)| a.saturating_sub(b));
        let mut m = s.serialize_map(Some(self.order.len()))?;
        for &i in self.order {
            match self.cells.get(i) {
                Some((name, v)) => m.serialize_entry(name, v)?,
                None => m.serialize_entry("round_trip_ns", &rtt)?,
            }
        }
        m.end()
    }
}

impl Row {
    /// Writes the tick's messages: its joint state, its control message, an event for a reply
    /// not applied or drives that held or rejected, and (with a painter, every `n`-th tick) its
    /// scene.
    pub(super) fn write(
        &self,
        out: &mut impl Bus,
        ch: &Channels,
        law: &str,
        cols: &Columns,
        ts_ns: u64,
        painter: Option<(&mut Painter, u64)>,
    ) -> Result<()> {
        let r = self;
        let t = r.k * ts_ns;
        let all = |g: [Option<f64>; 3]| g.map(|x| x.unwrap_or(f64::NAN));
        let [q, qd, tau_a] = JOINT_STATE.map(|name| all(r.group(name)));
        out.write(ch.joints, t, &cdr::joint_state(t, &q, &qd, &tau_a))?;
        let t_s = t as f64 * 1e-9;
        out.json(
            ch.control,
            t,
            &Control {
                row: self,
                cols,
                t_s,
            },
        )?;
        if r.reply != "applied" {
            out.log(
                ch.events,
                t,
                WARNING,
                law,
                format!("tick {}: reply {}", r.k, r.reply),
            )?;
        }
        if matches!(r.drives.as_str(), "held" | "rejected") {
            out.log(
                ch.events,
                t,
                INFO,
                law,
                format!("tick {}: drives {}", r.k, r.drives),
            )?;
        }
        let painter = painter.and_then(|(p, n)| r.k.is_multiple_of(n).then_some(p));
        if let Some(scene) = painter
            .map(|p| p.draw(r.k, t, &Vec3::from(q)))
            .transpose()?
            .flatten()
        {
            out.write(ch.scene, t, scene)?;
        }
        Ok(())
    }
}
