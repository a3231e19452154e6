//! One law's run as it is recorded: where its finished ticks go (the streaming metrics, its part
//! of `trace.csv`, and, for figures of short runs, the records themselves) and what is left once
//! it ends ([`LawRun`]). Every loop mode records through [`LawRecorder`].

use anyhow::Result;
use deltaloop_config::{Compensation, Law};
use deltaloop_model::Vec3;
use deltaloop_report::TraceWriter;
use deltaloop_report::mcap::Live;
use deltaloop_study::Study;
use deltaloop_study::record::metrics::{LawMetrics, MetricsAcc};
use deltaloop_study::record::{Recorder, RunEnd, Shadow, TickRecord, TickSink};
use deltaloop_study::reference::RefRow;
use deltaloop_transport::wire::StateMsg;
use std::path::PathBuf;
use std::sync::Arc;

/// A sink of each law's finished ticks beyond the run's files (the ROS 2 live topics), made when
/// the law starts recording. If it cannot be made the law runs without it (a warning line).
pub type TapFn = dyn Fn(&Study, Law) -> Result<Box<dyn TickSink + Send>> + Send + Sync;

/// A [`TapFn`] to hand around.
#[derive(Clone)]
pub struct Tap(pub Arc<TapFn>);

impl std::fmt::Debug for Tap {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("Tap")
    }
}

/// What to keep of a law's ticks besides the metrics.
#[derive(Clone, Debug, Default)]
pub struct Keep {
    /// Stream the rows to this part file of `trace.csv`.
    pub trace: Option<PathBuf>,
    /// Keep every record in memory (for figures; only for runs known to be short).
    pub records: bool,
    /// Write this MCAP file of the law while it records.
    pub mcap: Option<PathBuf>,
    /// Also hand every finished tick to this sink.
    pub tap: Option<Tap>,
}

/// The sinks of one law's ticks.
pub struct RunSinks<'a> {
    metrics: MetricsAcc<'a>,
    trace: Option<TraceWriter>,
    records: Option<Vec<TickRecord>>,
    mcap: Option<Live>,
    /// The first MCAP write error (the file then stops; the run and its trace go on).
    mcap_error: Option<anyhow::Error>,
    tap: Option<Box<dyn TickSink + Send>>,
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
        if let Some(m) = &mut self.mcap
            && let Err(e) = m.take(r, row, n_true)
        {
            self.mcap_error = Some(e);
            self.mcap = None;
        }
        if let Some(t) = &mut self.tap {
            t.take(r, row, n_true);
        }
    }

    fn recorded(&mut self, r: &TickRecord, row: &RefRow) {
        if let Some(t) = &mut self.tap {
            t.recorded(r, row);
        }
    }
}

impl RunSinks<'_> {
    /// Whether [`Self::timing`] has anywhere to write.
    pub fn wants_timing(&self) -> bool {
        self.mcap.is_some()
    }

    /// Whether the trace could not be written (a full disk): the run stops there.
    pub fn failed(&self) -> bool {
        self.trace.as_ref().is_some_and(TraceWriter::failed)
    }

    /// Hands the trace rows written so far to the kernel (a failure shows in [`Self::failed`]).
    pub fn flush(&mut self) {
        if let Some(t) = &mut self.trace {
            t.flush();
        }
    }

    /// Tick k's timing row (process modes), for the MCAP file.
    pub fn timing(&mut self, cells: &[Option<u64>; 13]) {
        if let Some(m) = &mut self.mcap
            && let Err(e) = m.timing(cells)
        {
            self.mcap_error = Some(e);
            self.mcap = None;
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
            .map(|p| {
                let compensated = study.config.controller.compensate != Compensation::None;
                TraceWriter::create(p, law, compensated)
            })
            .transpose()?,
        records: keep.records.then(|| Vec::with_capacity(reference.n + 1)),
        mcap: keep
            .mcap
            .as_deref()
            .map(|p| Live::create(p, study, law))
            .transpose()?,
        mcap_error: None,
        tap: keep.tap.as_ref().and_then(|t| match (t.0)(study, law) {
            Ok(s) => Some(s),
            Err(e) => {
                eprintln!("warning: `{law}` runs without its live view: {e:#}");
                None
            }
        }),
    };
    // A compensated built-in law's M̂ for the trace (a controller of the user's has its own;
    // without a trace nobody reads it).
    let shadow = (keep.trace.is_some() && study.config.controller.command.is_empty())
        .then(|| Shadow::of(study.controller_side(law)))
        .flatten();
    Ok(Recorder::new(law, reference, study.params.m_bar, sinks).with_shadow(shadow))
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
    let metrics = sinks.metrics.finish(&end);
    if let Some(e) = sinks.mcap_error {
        return Err(e.context("the run's MCAP file"));
    }
    if let Some(m) = sinks.mcap {
        m.finish(&serde_json::to_value(&metrics)?)?;
    }
    Ok(LawRun {
        law: end.law,
        metrics,
        records: sinks.records.unwrap_or_default(),
        end,
    })
}
