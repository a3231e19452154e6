//! The figures (supervisor/plot: line charts, latency by percentile, latency over run time) and
//! the one that needs the supervisor's own timing record.

pub use deltaloop_plot::*;

use anyhow::Result;
use deltaloop_timing::Timing;
use hdrhistogram::Histogram;
use std::path::{Path, PathBuf};

/// The figures of one law's run in `dir`: `<prefix>latency.{png,svg}` (percentiles of round
/// trip, wake lateness, state → controller and compute; the budget in realtime) and
/// `<prefix>timeline.{png,svg}`. `what` names the run in the titles (e.g. "tdc, realtime").
/// Returns the two PNG paths.
pub fn timing_figures(
    dir: &Path,
    prefix: &str,
    what: &str,
    t: &Timing,
    budget_us: f64,
) -> Result<[PathBuf; 2]> {
    let budget = t.realtime.then_some(budget_us);
    let hists: Vec<(&str, &Histogram<u64>)> = [
        ("round trip", &t.round_trip),
        ("wake lateness", &t.wake_lateness),
        ("state → controller", &t.state_to_controller),
        ("controller compute", &t.compute),
    ]
    .into_iter()
    .map(|(label, d)| (label, &d.hist))
    .collect();
    let lat = dir.join(format!("{prefix}latency"));
    let s = t.summary();
    latency_percentiles_colored(
        &lat,
        &format!(
            "{what}: latency by percentile ({} ticks, {} misses)",
            s.ticks, s.deadline_misses
        ),
        &hists,
        &[
            quantity_color("round_trip"),
            quantity_color("wake_lateness"),
            quantity_color("state_to_controller"),
            quantity_color("controller_compute"),
        ],
        budget,
    )?;
    let tl = dir.join(format!("{prefix}timeline"));
    let bins: Vec<TimeBin> = t.timeline.bins().collect();
    timeline(
        &tl,
        &format!("{what}: latency over run time"),
        &bins,
        t.realtime,
        budget,
    )?;
    Ok([with_ext(&lat, "png"), with_ext(&tl, "png")])
}
