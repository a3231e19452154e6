//! One law's run as it is recorded: where its finished ticks go (the streaming metrics, its part
//! of `trace.csv`, and, for figures of short runs, the records themselves) and what is left once
//! it ends ([`LawRun`]). Every loop mode records through [`LawRecorder`].

use crate::output::TraceWriter;
use crate::record::metrics::{LawMetrics, MetricsAcc};
use crate::record::{Recorder, RunEnd, TickRecord, TickSink};
use crate::study::Study;
use crate::study::reference::RefRow;
use anyhow::Result;
use deltaloop_config::Law;
use deltaloop_model::Vec3;
use deltaloop_transport::wire::StateMsg;
use std::path::PathBuf;

/// What to keep of a law's ticks besides the metrics.
#[derive(Clone, Debug, Default)]
pub struct Keep {
    /// Stream the rows to this part file of `trace.csv`.
    pub trace: Option<PathBuf>,
    /// Keep every record in memory (for figures; only for runs known to be short).
    pub records: bool,
}

/// The sinks of one law's ticks.
pub struct RunSinks<'a> {
    metrics: MetricsAcc<'a>,
    trace: Option<TraceWriter>,
    records: Option<Vec<TickRecord>>,
}

impl TickSink for RunSinks<'_> {
    fn take(&mut self, r: &TickRecord, row: &RefRow, n_true: Option<Vec3>) {
        self.metrics.push(r, row, n_true);
        if let Some(t) = &mut self.trace {
            t.write(r, row, n_true);
        }
        if let Some(v) = &mut self.records {
            v.push(*r);
        }
    }
}

/// The recorder every loop mode fills for one law.
pub type LawRecorder<'a> = Recorder<'a, RunSinks<'a>>;

/// A recorder for `law` over the study, streaming to what `keep` asks for.
pub fn recorder<'a>(study: &'a Study, law: Law, keep: &Keep) -> Result<LawRecorder<'a>> {
    let reference = &study.reference;
    let sinks = RunSinks {
        metrics: MetricsAcc::new(law, reference.n, reference.ts, &study.robot, &study.params),
        trace: keep
            .trace
            .as_deref()
            .map(|p| TraceWriter::create(p, law))
            .transpose()?,
        records: keep.records.then(|| Vec::with_capacity(reference.n + 1)),
    };
    Ok(Recorder::new(law, reference, study.params.m_bar, sinks))
}

/// A finished run of one law.
#[derive(Clone, Debug)]
pub struct LawRun {
    pub law: Law,
    pub metrics: LawMetrics,
    /// How the run ended.
    pub end: RunEnd,
    /// Every recorded tick, if [`Keep::records`] asked for them (else empty).
    pub records: Vec<TickRecord>,
}

/// Ends the recording: closes the open ticks, flushes the trace part, computes the metrics.
pub fn finish(rec: LawRecorder<'_>, after: Option<&StateMsg>) -> Result<LawRun> {
    let (end, sinks) = rec.finish(after);
    if let Some(t) = sinks.trace {
        t.finish()?;
    }
    Ok(LawRun {
        law: end.law,
        metrics: sinks.metrics.finish(&end),
        records: sinks.records.unwrap_or_default(),
        end,
    })
}
