//! `[record]`: which per-tick files a run writes.

use crate::keys::RecordKeys;
use serde::{Deserialize, Serialize};

/// `[record]`: which per-tick files a run writes. Both are on by default: every tick of every law
/// on disk, which is what replay and offline analysis need. A soak that only watches timing can
/// turn them off: the summary, report, histograms, interval logs and figures do not depend on
/// them, and disk no longer grows with the run's length (≈ 630 B a tick for the trace, ≈ 106 B for
/// the timing file).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RecordSection {
    /// Write `trace.csv` (joint states, torques, errors and estimates of every tick). Without it a
    /// run cannot be replayed.
    pub trace: bool,

    /// Write `<law>.timing.csv` (the raw clock stamps of every tick) in realtime and lockstep runs.
    pub timing_csv: bool,

    /// Realtime: record the kernel's scheduling events on the loop's CPUs while each law runs,
    /// and name the cause of each missed or late tick (`<law>.misses.csv`,
    /// docs/guide/misses.md). Needs root and tracefs; without them one warning, and the run goes
    /// on.
    pub explain: bool,
}

impl Default for RecordSection {
    fn default() -> Self {
        Self {
            trace: RecordKeys::trace(),
            timing_csv: RecordKeys::timing_csv(),
            explain: RecordKeys::explain(),
        }
    }
}
