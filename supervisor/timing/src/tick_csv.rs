//! `<law>.timing.csv`: one row per tick of what the supervisor saw, written as the run goes.

use super::*;
use deltaloop_config::RemoteSide;

/// The columns of `<law>.timing.csv` (and of the MCAP file's timing channel).
pub const TIMING_COLUMNS: [&str; 13] = [
    "k",
    "deadline_ns",
    "wake_ns",
    "state_pub_ns",
    "ctrl_rx_ns",
    "ctrl_pub_ns",
    "torque_rx_ns",
    "missed",
    "held",
    "clamped",
    "ctrl_skipped",
    "arrival_ns",
    "link_rtt_ns",
];

/// Tick k's timing row in [`TIMING_COLUMNS`] order (None: that message was not seen), or None
/// if the supervisor saw nothing of the tick. `link`: which process is across the link, if one
/// is (the `link_rtt_ns` column is filled).
pub fn timing_cells(seen: &Seen, link: Option<RemoteSide>) -> Option<[Option<u64>; 13]> {
    let (s, t, m) = (seen.state, seen.torque, seen.tel);
    if s.is_none() && t.is_none() && m.is_none() {
        return None;
    }
    let flag = |bit: u32| m.map(|m| u64::from(m.flags & bit != 0));
    Some([
        Some(seen.k),
        s.map(|s| s.t_deadline_ns),
        s.map(|s| s.t_wake_ns),
        s.map(|s| s.t_publish_ns),
        t.map(|t| t.t_state_rx_ns),
        t.map(|t| t.t_publish_ns),
        m.and_then(|m| (m.t_torque_rx_ns > 0).then_some(m.t_torque_rx_ns)),
        flag(wire::TEL_MISSED),
        flag(wire::TEL_HELD),
        flag(wire::TEL_CLAMPED),
        t.map(|t| t.skipped),
        m.filter(|m| m.flags & (wire::TEL_MISSED | wire::TEL_SAFE_STOP) == 0)
            .map(|m| m.arrival_ns),
        m.zip(t)
            .zip(link)
            .and_then(|((m, t), across)| link_rtt_ns(across, &m, s.as_ref(), &t)),
    ])
}

/// `<law>.timing.csv`, written a tick at a time: the raw CLOCK_MONOTONIC stamps of every tick (ns)
/// and the plant's flags, so any latency can be recomputed. Empty cells: the supervisor did not
/// see that message.
pub struct TimingCsv {
    path: std::path::PathBuf,
    w: csv::Writer<std::fs::File>,
    fields: [String; 13],
    link: Option<RemoteSide>,
}

impl TimingCsv {
    /// `link`: which process is across the link, if one is (the `link_rtt_ns` column is filled).
    pub fn create(path: &Path, link: Option<RemoteSide>) -> Result<Self> {
        let mut w = csv::Writer::from_path(path)
            .with_context(|| format!("cannot create {}", path.display()))?;
        w.write_record(TIMING_COLUMNS)
            .with_context(|| format!("cannot write {}", path.display()))?;
        Ok(Self {
            path: path.to_path_buf(),
            w,
            fields: Default::default(),
            link,
        })
    }

    /// Writes tick k's row, unless the supervisor saw nothing of it.
    pub fn write(&mut self, seen: &Seen) -> Result<()> {
        let Some(cells) = timing_cells(seen, self.link) else {
            return Ok(());
        };
        for (f, v) in self.fields.iter_mut().zip(cells) {
            use std::fmt::Write as _;
            f.clear();
            if let Some(v) = v {
                let _ = write!(f, "{v}");
            }
        }
        self.w
            .write_record(&self.fields)
            .with_context(|| format!("cannot write {}", self.path.display()))
    }

    /// Hands the rows written so far to the kernel (a killed run keeps them).
    pub fn flush(&mut self) -> Result<()> {
        self.w
            .flush()
            .with_context(|| format!("cannot write {}", self.path.display()))
    }

    pub fn finish(mut self) -> Result<()> {
        self.flush()
    }
}
