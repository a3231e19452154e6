//! What the timeline figure draws of each bin of ticks (the bins are kept by the supervisor's
//! `timing::timeline`, in fixed memory over the run).

/// Min, max and sum of the values of one bin, ns.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Stat {
    pub n: u64,
    pub min: u64,
    pub max: u64,
    pub sum: u64,
}

impl Stat {
    pub fn add(&mut self, v: u64) {
        if self.n == 0 || v < self.min {
            self.min = v;
        }
        self.max = self.max.max(v);
        self.sum = self.sum.saturating_add(v);
        self.n += 1;
    }

    /// Mean, ns (None: no value).
    pub fn mean(&self) -> Option<f64> {
        (self.n > 0).then(|| self.sum as f64 / self.n as f64)
    }
}

/// One bin of ticks.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Bin {
    pub round_trip: Stat,
    pub wake_lateness: Stat,
    /// Ticks whose torque was not applied (deadline misses).
    pub misses: u64,
}
