//! HdrHistogram interval logs (`.hlog`): one histogram per interval of run time, in the standard
//! interval-log format (the Java `HistogramLogWriter`'s, read by `HistogramLogProcessor`, the
//! Python `hdrh` package and the Rust crate), each histogram in the compressed V2 encoding.
//!
//! [`HlogWriter`] is filled while a run streams: an interval goes to disk, flushed, as soon as a
//! sample (or [`HlogWriter::advance`]) shows it is over, so a killed run leaves every completed
//! interval behind, and memory holds one interval whatever the run's length.

use anyhow::{Context, Result, anyhow};
use base64::Engine as _;
use hdrhistogram::Histogram;
use hdrhistogram::serialization::interval_log::{
    IntervalLogIterator, IntervalLogWriterBuilder, LogEntry,
};
use hdrhistogram::serialization::{Deserializer, V2DeflateSerializer};
use std::fs::File;
use std::io::{BufWriter, Write as _};
use std::path::{Path, PathBuf};
use std::time::{Duration, SystemTime};

/// Writes one interval log, intervals of fixed length in run time (ns since the log's base time).
pub struct HlogWriter {
    path: PathBuf,
    out: BufWriter<File>,
    ser: V2DeflateSerializer,
    /// The open interval.
    hist: Histogram<u64>,
    interval_ns: u64,
    /// Start of the open interval, ns since the base time.
    start_ns: u64,
}

impl HlogWriter {
    /// Creates `path` and writes the header: `what` as a comment, the format version, StartTime
    /// and BaseTime (both `base`: interval timestamps are seconds since it) and the legend.
    /// `template` gives the histograms' bounds and precision (it is not recorded).
    pub fn create(
        path: &Path,
        what: &str,
        base: SystemTime,
        interval: Duration,
        template: &Histogram<u64>,
    ) -> Result<Self> {
        let io = |e: std::io::Error| anyhow!("cannot write {}: {e}", path.display());
        let file = File::create(path).map_err(io)?;
        let mut out = BufWriter::new(file);
        let mut ser = V2DeflateSerializer::new();
        IntervalLogWriterBuilder::new()
            .add_comment(what)
            .add_comment("[Histogram log format version 1.3]")
            .with_start_time(base)
            .with_base_time(base)
            .begin_log_with(&mut out, &mut ser)
            .map_err(io)?;
        writeln!(
            out,
            "\"StartTimestamp\",\"Interval_Length\",\"Interval_Max\",\"Interval_Compressed_Histogram\""
        )
        .and_then(|()| out.flush())
        .map_err(io)?;
        Ok(Self {
            path: path.to_path_buf(),
            out,
            ser,
            hist: Histogram::new_from(template),
            interval_ns: interval.as_nanos().max(1) as u64,
            start_ns: 0,
        })
    }

    /// Records `value` at run time `t_ns` (ns since the base time, not decreasing from call to
    /// call), after writing every interval that ended at or before `t_ns`.
    pub fn record(&mut self, t_ns: u64, value: u64) -> Result<()> {
        self.advance(t_ns)?;
        self.hist.saturating_record(value);
        Ok(())
    }

    /// Run time moved on to `t_ns`: writes (and flushes) every interval that ended at or before
    /// it, empty ones included, so the log has one line per interval.
    pub fn advance(&mut self, t_ns: u64) -> Result<()> {
        if t_ns < self.start_ns + self.interval_ns {
            return Ok(());
        }
        while t_ns >= self.start_ns + self.interval_ns {
            self.write_interval(self.interval_ns)?;
        }
        self.out
            .flush()
            .with_context(|| format!("cannot write {}", self.path.display()))
    }

    /// Writes the open interval, `len_ns` long, and starts the next one.
    fn write_interval(&mut self, len_ns: u64) -> Result<()> {
        IntervalLogWriterBuilder::new()
            .begin_log_with(&mut self.out, &mut self.ser)
            .map_err(anyhow::Error::from)
            .and_then(|mut w| {
                w.write_histogram(
                    &self.hist,
                    Duration::from_nanos(self.start_ns),
                    Duration::from_nanos(len_ns),
                    None,
                )
                .map_err(|e| anyhow!("{e}"))
            })
            .with_context(|| format!("cannot write {}", self.path.display()))?;
        self.hist.reset();
        self.start_ns += self.interval_ns;
        Ok(())
    }

    /// Writes the last interval, cut at `end_ns` (the end of the run; nothing if the run ended
    /// exactly on an interval's end), and flushes.
    pub fn finish(mut self, end_ns: u64) -> Result<()> {
        self.advance(end_ns)?;
        if end_ns > self.start_ns || !self.hist.is_empty() {
            let len = end_ns.saturating_sub(self.start_ns).max(1);
            self.write_interval(len)?;
        }
        self.out
            .flush()
            .with_context(|| format!("cannot write {}", self.path.display()))
    }
}

/// One interval read back from a log.
#[derive(Debug, Clone)]
pub struct Interval {
    /// Start, s since the base time.
    pub start_s: f64,
    /// Length, s.
    pub length_s: f64,
    pub hist: Histogram<u64>,
}

/// A log read back: its BaseTime (s since the epoch, if given) and intervals.
#[derive(Debug, Clone)]
pub struct Hlog {
    pub base_time_s: Option<f64>,
    pub start_time_s: Option<f64>,
    pub intervals: Vec<Interval>,
}

/// Largest interval log read back, bytes: a line per second of run time, of a few hundred bytes
/// to a few KiB, so a day's soak (the longest) stays well under it.
const MAX_LOG_BYTES: u64 = 512 << 20;

/// Reads an interval log (whole file in memory: for tests and tools, not for the run).
pub fn read(path: &Path) -> Result<Hlog> {
    let mut intervals = Vec::new();
    let (base_time_s, start_time_s) = each_interval(path, |i| {
        intervals.push(i);
        Ok(())
    })?;
    Ok(Hlog {
        base_time_s,
        start_time_s,
        intervals,
    })
}

/// Reads an interval log, handing each interval to `each` as it is decoded (memory: the file
/// and one interval's histogram); returns its BaseTime and StartTime (s since the epoch).
pub fn each_interval(
    path: &Path,
    mut each: impl FnMut(Interval) -> Result<()>,
) -> Result<(Option<f64>, Option<f64>)> {
    let bytes = deltaloop_config::files::read_regular(path, MAX_LOG_BYTES, "an interval log")
        .map_err(|e| anyhow!("cannot read {}: {e}", path.display()))?;
    let bad = |what: &str| anyhow!("{}: {what}", path.display());
    let (mut base, mut start) = (None, None);
    for entry in IntervalLogIterator::new(&bytes) {
        match entry.map_err(|e| bad(&format!("not an interval log ({e:?})")))? {
            LogEntry::StartTime(t) => start = Some(t.as_secs_f64()),
            LogEntry::BaseTime(t) => base = Some(t.as_secs_f64()),
            LogEntry::Interval(i) => {
                let raw = base64::engine::general_purpose::STANDARD
                    .decode(i.encoded_histogram())
                    .map_err(|e| bad(&format!("interval is not base64 ({e})")))?;
                let hist = decode(&raw).map_err(|e| {
                    bad(&format!(
                        "interval at {} s: {e}",
                        i.start_timestamp().as_secs_f64()
                    ))
                })?;
                each(Interval {
                    start_s: i.start_timestamp().as_secs_f64(),
                    length_s: i.duration().as_secs_f64(),
                    hist,
                })?;
            }
        }
    }
    Ok((base, start))
}

/// The cookies of HdrHistogram's V2 encoding: plain, and deflated (`V2DeflateSerializer`).
const V2_COOKIE: u32 = 0x1c84_9313;
const V2_COMPRESSED_COOKIE: u32 = 0x1c84_9314;
/// The plain V2 header, bytes: cookie, payload length, normalizing offset, significant digits,
/// lowest and highest trackable value, integer-to-double ratio.
const V2_HEADER_BYTES: usize = 40;
/// Deflate's largest expansion: at most 1032 bytes out of each byte in.
const DEFLATE_MAX_RATIO: u64 = 1032;

/// Decodes one V2 histogram (deflated or plain), checking each length its header claims against
/// the bytes there are before anything is allocated for it (regression: a 360-byte log whose
/// header claimed a 4 GiB payload had 4 GiB allocated). What a payload inflates to is bounded by
/// deflate's ratio; the counts array the header's range and digits ask for (at most about 70 MB
/// at 5 digits over the whole u64 range) is the one allocation not tied to the file's size.
fn decode(raw: &[u8]) -> std::result::Result<Histogram<u64>, String> {
    use std::io::Read as _;
    let word = |b: &[u8], at: usize| {
        b.get(at..at + 4)
            .map(|w| u32::from_be_bytes([w[0], w[1], w[2], w[3]]))
    };
    let inflated;
    let plain: &[u8] = match word(raw, 0) {
        Some(V2_COMPRESSED_COOKIE) => {
            let body = raw.get(8..).unwrap_or_default();
            let len = word(raw, 4).unwrap_or(u32::MAX) as usize;
            if len > body.len() {
                return Err(format!(
                    "its compressed payload claims {len} bytes, {} are there",
                    body.len()
                ));
            }
            let mut out = Vec::new();
            flate2::read::ZlibDecoder::new(&body[..len])
                .take(DEFLATE_MAX_RATIO * len as u64)
                .read_to_end(&mut out)
                .map_err(|e| format!("its payload does not inflate ({e})"))?;
            inflated = out;
            &inflated
        }
        Some(V2_COOKIE) => raw,
        _ => return Err("not a V2 histogram (unknown cookie)".into()),
    };
    if word(plain, 0) != Some(V2_COOKIE) {
        return Err("not a V2 histogram (unknown cookie inside)".into());
    }
    let claimed = word(plain, 4).unwrap_or(u32::MAX) as usize;
    let there = plain.len().saturating_sub(V2_HEADER_BYTES);
    if plain.len() < V2_HEADER_BYTES || claimed > there {
        return Err(format!(
            "its histogram's payload claims {claimed} bytes of counts, {there} are there"
        ));
    }
    Deserializer::new()
        .deserialize(&mut &plain[..])
        .map_err(|e| format!("not a V2 histogram ({e:?})"))
}

/// The wall-clock time of a CLOCK_MONOTONIC stamp (ns) from the past: now minus its age.
pub fn system_time_of(monotonic_ns: u64) -> SystemTime {
    let age = deltaloop_transport::rt::now_ns().saturating_sub(monotonic_ns);
    SystemTime::now() - Duration::from_nanos(age)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn template() -> Histogram<u64> {
        crate::latency_histogram()
    }

    /// Samples land in the interval of their time; skipped seconds still get their (empty)
    /// line; the last interval is cut at the end; the header round-trips.
    #[test]
    fn intervals_hold_their_samples_and_every_second_has_a_line() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("x.hlog");
        let base = SystemTime::UNIX_EPOCH + Duration::from_secs(1_700_000_000);
        let s = 1_000_000_000;
        let mut w =
            HlogWriter::create(&path, "test", base, Duration::from_secs(1), &template()).unwrap();
        w.record(0, 10).unwrap();
        w.record(s - 1, 20).unwrap();
        // Interval 0 is on disk as soon as time passes 1 s, before finish.
        w.record(s, 30).unwrap();
        assert_eq!(read(&path).unwrap().intervals.len(), 1);
        w.record(3 * s + 5, 40).unwrap();
        w.finish(3 * s + s / 2).unwrap();
        let log = read(&path).unwrap();
        assert_eq!(log.base_time_s, Some(1_700_000_000.0));
        assert_eq!(log.start_time_s, Some(1_700_000_000.0));
        let got: Vec<(f64, f64, u64)> = log
            .intervals
            .iter()
            .map(|i| (i.start_s, i.length_s, i.hist.len()))
            .collect();
        assert_eq!(
            got,
            [(0.0, 1.0, 2), (1.0, 1.0, 1), (2.0, 1.0, 0), (3.0, 0.5, 1)]
        );
        assert_eq!(log.intervals[3].hist.max(), 40);
        let text = std::fs::read_to_string(&path).unwrap();
        assert!(text.starts_with("#test\n#[Histogram log format version 1.3]\n"));
        assert!(text.contains(",HISTFAAA"), "compressed V2 payloads: {text}");
    }
}
