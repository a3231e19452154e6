//! Round trip and wake lateness over run time, in fixed memory: the ticks are cut into at most
//! [`BINS`] bins (about one pixel column of the figure each) that keep the min, max and mean of
//! each quantity and the misses, so an hour's run draws as its envelope without keeping a tick.

/// Bins at most (the figure's plot area is about this many pixels wide).
pub const BINS: u64 = 1000;

pub use deltaloop_plot::timeline::{Bin, Stat};

/// The run's bins; tick k belongs to bin k / ticks_per_bin, at run time k·Ts.
#[derive(Clone, Debug, Default)]
pub struct Timeline {
    ticks_per_bin: u64,
    ts_ns: u64,
    bins: Vec<Bin>,
}

impl Timeline {
    /// For ticks 0..=`ticks` at period `ts_ns` (ns). Allocates here, once.
    pub fn new(ticks: u64, ts_ns: u64) -> Self {
        let per = (ticks + 1).div_ceil(BINS).max(1);
        Self {
            ticks_per_bin: per,
            ts_ns,
            bins: vec![Bin::default(); (ticks + 1).div_ceil(per) as usize],
        }
    }

    /// Tick k's bin (None beyond the run).
    pub fn bin_mut(&mut self, k: u64) -> Option<&mut Bin> {
        let i = usize::try_from(k / self.ticks_per_bin.max(1)).ok()?;
        self.bins.get_mut(i)
    }

    /// The bins up to the last one with a value or a miss: (start, end) of each in run time, s.
    pub fn bins(&self) -> impl Iterator<Item = (f64, f64, &Bin)> {
        let used = self
            .bins
            .iter()
            .rposition(|b| b.round_trip.n + b.wake_lateness.n + b.misses > 0)
            .map_or(0, |i| i + 1);
        let w = self.ticks_per_bin as f64 * self.ts_ns as f64 * 1e-9;
        self.bins[..used]
            .iter()
            .enumerate()
            .map(move |(i, b)| (i as f64 * w, (i + 1) as f64 * w, b))
    }

    /// Ticks per bin.
    pub fn ticks_per_bin(&self) -> u64 {
        self.ticks_per_bin
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bins_stay_bounded_and_keep_extremes_and_misses() {
        // One hour at 3.3 kHz.
        let n = 12_000_000;
        let mut t = Timeline::new(n, 300_000);
        assert!(t.bins.len() as u64 <= BINS && t.bins.len() as u64 >= BINS - 1);
        for k in 0..=n {
            let b = t.bin_mut(k).unwrap();
            b.round_trip
                .add(if k == 5_000_000 { 900_000 } else { 30_000 });
            b.misses += u64::from(k == 7_000_000);
        }
        assert!(t.bin_mut(n + t.ticks_per_bin()).is_none());
        let bins: Vec<_> = t.bins().collect();
        assert_eq!(bins.iter().map(|b| b.2.round_trip.n).sum::<u64>(), n + 1);
        let peak = bins.iter().find(|b| b.2.round_trip.max == 900_000).unwrap();
        assert!(
            peak.0 <= 1500.0 && 1500.0 < peak.1,
            "{:?}",
            (peak.0, peak.1)
        );
        assert_eq!(peak.2.round_trip.min, 30_000);
        let miss = bins.iter().find(|b| b.2.misses == 1).unwrap();
        assert!(miss.0 <= 2100.0 && 2100.0 < miss.1);
        let end = bins.last().unwrap().1;
        assert!((3600.0..3600.0 + 3.7).contains(&end), "{end}");
    }
}
