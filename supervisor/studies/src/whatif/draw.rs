//! How a replica's latencies are drawn from the pooled records, and the arrival schedule they
//! make for the in-process loop.
//!
//! A drawn latency L (ns after the tick's state was published) meets the realtime arrival rule
//! with the plant on time: a reply with L ≤ the torque budget acts at L, any later one is a miss
//! and the drives hold. A record's late, skipped and missed ticks stay so at every scale (their
//! latency is unknown beyond the budget).

use super::source::{Latencies, Source};
use anyhow::{Result, bail};
use deltaloop_plant_tick::ReplyOutcome;
use deltaloop_runner::inproc::Schedule;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// The draw model.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Model {
    /// Circular blocks of `ticks` consecutive ticks of one recorded sequence: each replica first
    /// draws a sequence (weighted by its length) from the pool, then its blocks from it, each
    /// starting at a uniformly drawn tick. Keeps bursts up to a block long, and the difference
    /// between records (a run the host disturbed more than another).
    Block { ticks: usize },
    /// Every tick drawn on its own from the pooled distribution: keeps the distribution, not
    /// its order.
    Independent,
    /// Each law's own recorded sequence, in order, as it was (one run folder, one replica): the
    /// replay.
    AsRecorded,
}

impl Model {
    /// The name in the output.
    pub fn name(self) -> &'static str {
        match self {
            Model::Block { .. } => "block-bootstrap",
            Model::Independent => "independent",
            Model::AsRecorded => "as-recorded",
        }
    }

    /// One line for the terminal and the report.
    pub fn describe(self, ts_s: f64) -> String {
        match self {
            Model::Block { ticks } => format!(
                "block bootstrap: circular blocks of {ticks} ticks ({:.3} s) of one record per replica, drawn from the pool",
                ticks as f64 * ts_s
            ),
            Model::Independent => {
                "independent draws from the pooled distribution (no bursts)".into()
            }
            Model::AsRecorded => "as recorded: each law's own sequence, in order".into(),
        }
    }
}

/// The pooled latencies, ready to draw from.
pub struct Pool {
    /// Every recorded sequence (block bootstrap).
    seqs: Vec<Vec<ReplyOutcome>>,
    /// Cumulative lengths of `seqs`: a replica's sequence is drawn weighted by its length.
    seq_ends: Vec<u64>,
    /// Every distinct outcome with its cumulative weight (independent draws).
    items: Vec<(ReplyOutcome, u64)>,
}

impl Pool {
    /// Pools `sources` for `model`. A block bootstrap needs sequences, and takes them out of
    /// the sources (held once, not twice); independent draws take any source and keep only the
    /// distribution (each distinct outcome once, whatever the record's length).
    pub fn new(sources: &mut [Source], model: Model) -> Result<Self> {
        let sources_len = sources.len();
        let mut seqs = Vec::new();
        // Sorted as `ReplyOutcome` orders: replies by latency, then late, skipped, missed.
        let mut counts: std::collections::BTreeMap<ReplyOutcome, u64> = Default::default();
        for s in sources.iter_mut() {
            match &mut s.latencies {
                Latencies::Sequences(v) => {
                    for t in v.iter().flatten() {
                        *counts.entry(*t).or_default() += 1;
                    }
                    if let Model::Block { .. } = model {
                        seqs.extend(std::mem::take(v).into_iter().filter(|s| !s.is_empty()));
                    }
                }
                Latencies::Histogram(h) => {
                    if let Model::Block { .. } = model {
                        bail!(
                            "--latency {}: an HdrHistogram file keeps no order, so a block bootstrap cannot draw from it: use --draw independent",
                            s.path.display()
                        );
                    }
                    for &(v, c) in h.iter() {
                        let n = counts.entry(ReplyOutcome::Applied(v)).or_default();
                        *n = n.checked_add(c).ok_or_else(|| past_2_64(sources_len))?;
                    }
                }
            }
        }
        let mut seq_ends = Vec::with_capacity(seqs.len());
        let mut total = 0u64;
        for s in &seqs {
            total += s.len() as u64;
            seq_ends.push(total);
        }
        let mut cum = 0u64;
        let items = counts
            .into_iter()
            .filter(|&(_, c)| c > 0)
            .map(|(t, c)| {
                cum = cum.checked_add(c).ok_or_else(|| past_2_64(sources_len))?;
                Ok((t, cum))
            })
            .collect::<Result<_>>()?;
        Ok(Self {
            seqs,
            seq_ends,
            items,
        })
    }

    /// Every pooled outcome with its weight, ascending: (outcome, count).
    pub fn distribution(&self) -> impl Iterator<Item = (ReplyOutcome, u64)> + '_ {
        let mut prev = 0;
        self.items.iter().map(move |&(t, cum)| {
            let c = cum - prev;
            prev = cum;
            (t, c)
        })
    }

    fn total_weight(&self) -> u64 {
        self.items.last().map_or(0, |i| i.1)
    }
}

/// The error for pooled counts past u64 (regression: they wrapped).
fn past_2_64(sources: usize) -> anyhow::Error {
    anyhow::anyhow!(
        "the {sources} --latency sources' counts add up past 2^64 latencies: not records of runs"
    )
}

/// One replica's arrival schedule: ticks 0..=`last`, each drawn as `model` says.
pub struct Drawn<'p> {
    pool: &'p Pool,
    model: Model,
    rng: ChaCha8Rng,
    /// Latencies are multiplied by this.
    scale: f64,
    budget_ns: u64,
    last: u64,
    /// The replica's sequence (block bootstrap).
    seq: usize,
    /// The block being read: (position, ticks left).
    block: (usize, usize),
    /// Ticks whose reply did not act (late, skipped, missed), so far.
    pub misses: u64,
}

impl<'p> Drawn<'p> {
    /// Replica `replica`'s schedule. Its draws depend on (`seed`, `replica`) only, so every law
    /// and every scale of a replica meet the same latencies (common random numbers: the laws
    /// are compared on equal terms, and the scale curve is smooth).
    pub fn new(
        pool: &'p Pool,
        model: Model,
        seed: u64,
        replica: u64,
        scale: f64,
        budget_ns: u64,
        last: u64,
    ) -> Self {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        rng.set_stream(replica);
        let seq = match model {
            Model::Block { .. } => {
                let total = pool.seq_ends.last().copied().unwrap_or(0);
                let u = rng.random_range(0..total.max(1));
                pool.seq_ends.partition_point(|&end| end <= u)
            }
            _ => 0,
        };
        Self {
            pool,
            model,
            rng,
            scale,
            budget_ns,
            last,
            seq,
            block: (0, 0),
            misses: 0,
        }
    }

    fn draw(&mut self) -> ReplyOutcome {
        match self.model {
            Model::Block { ticks } => {
                let seq = &self.pool.seqs[self.seq];
                if self.block.1 == 0 {
                    self.block = (self.rng.random_range(0..seq.len()), ticks.max(1));
                }
                let (pos, left) = self.block;
                self.block = ((pos + 1) % seq.len(), left - 1);
                seq[pos]
            }
            Model::Independent | Model::AsRecorded => {
                let u = self.rng.random_range(0..self.pool.total_weight().max(1));
                let i = self.pool.items.partition_point(|&(_, cum)| cum <= u);
                self.pool.items[i].0
            }
        }
    }

    /// What a drawn outcome becomes at this scale under the arrival rule.
    fn scaled(&self, t: ReplyOutcome) -> ReplyOutcome {
        match t {
            ReplyOutcome::Applied(l) => {
                let l = (l as f64 * self.scale).round() as u64;
                if l <= self.budget_ns {
                    ReplyOutcome::Applied(l)
                } else {
                    ReplyOutcome::Late
                }
            }
            ReplyOutcome::Late | ReplyOutcome::Skipped | ReplyOutcome::Missed => t,
        }
    }
}

impl Schedule for Drawn<'_> {
    fn outcome(&mut self, k: u64) -> Result<Option<ReplyOutcome>> {
        if k > self.last {
            return Ok(None);
        }
        let t = self.draw();
        let outcome = self.scaled(t);
        if !matches!(outcome, ReplyOutcome::Applied(_)) {
            self.misses += 1;
        }
        Ok(Some(outcome))
    }

    /// Ctrl-C ends a replica at once: whatif then writes nothing.
    fn interruptible(&self) -> bool {
        true
    }
}

/// A law's recorded sequence replayed in order, each reply at its recorded latency and every
/// verdict as the run's plant made it: the replay of that run.
pub struct AsRecorded<'r> {
    pub seq: &'r [ReplyOutcome],
    pub misses: u64,
}

impl Schedule for AsRecorded<'_> {
    fn outcome(&mut self, k: u64) -> Result<Option<ReplyOutcome>> {
        let Some(&t) = self.seq.get(k as usize) else {
            return Ok(None);
        };
        if !matches!(t, ReplyOutcome::Applied(_)) {
            self.misses += 1;
        }
        Ok(Some(t))
    }

    /// Ctrl-C ends a replica at once: whatif then writes nothing.
    fn interruptible(&self) -> bool {
        true
    }
}

#[cfg(test)]
mod tests {
    use super::super::source::Kind;
    use super::*;

    fn seq_source(seqs: Vec<Vec<ReplyOutcome>>) -> Source {
        Source {
            path: "x".into(),
            kind: Kind::Text,
            latencies: Latencies::Sequences(seqs),
            laws: vec![],
            ticks: 0,
            recorded: None,
        }
    }

    fn steps(d: &mut Drawn, n: u64) -> Vec<ReplyOutcome> {
        (0..n).map(|k| d.outcome(k).unwrap().unwrap()).collect()
    }

    /// A block is a run of consecutive recorded ticks (wrapping round its sequence); a replica
    /// draws all its blocks from one sequence, and the replicas from both; a replica's draws are
    /// the same whatever else runs.
    #[test]
    fn blocks_are_consecutive_ticks_of_one_sequence_and_replicas_repeat() {
        let a: Vec<ReplyOutcome> = (0..10).map(|i| ReplyOutcome::Applied(1000 + i)).collect();
        let b: Vec<ReplyOutcome> = (0..7).map(|i| ReplyOutcome::Applied(5000 + i)).collect();
        let pool = Pool::new(&mut [seq_source(vec![a, b])], Model::Block { ticks: 4 }).unwrap();
        let model = Model::Block { ticks: 4 };
        let mut d = Drawn::new(&pool, model, 7, 3, 1.0, 1_000_000, 99);
        let got = steps(&mut d, 100);
        for block in got.chunks(4) {
            let ls: Vec<u64> = block
                .iter()
                .map(|s| match s {
                    ReplyOutcome::Applied(l) => *l,
                    other => panic!("{other:?}"),
                })
                .collect();
            let (base, len) = if ls[0] >= 5000 { (5000, 7) } else { (1000, 10) };
            for w in ls.windows(2) {
                assert_eq!((w[1] - base), (w[0] - base + 1) % len, "{ls:?}");
            }
        }
        let from_b = |steps: &[ReplyOutcome]| {
            steps
                .iter()
                .all(|s| matches!(s, ReplyOutcome::Applied(l) if *l >= 5000))
        };
        let from_a = |steps: &[ReplyOutcome]| {
            steps
                .iter()
                .all(|s| matches!(s, ReplyOutcome::Applied(l) if *l < 5000))
        };
        assert!(
            from_a(&got) || from_b(&got),
            "one sequence per replica: {got:?}"
        );
        let (mut a, mut b) = (0, 0);
        for r in 0..100 {
            let mut d = Drawn::new(&pool, model, 7, r, 1.0, 1_000_000, 9);
            let s = steps(&mut d, 10);
            a += usize::from(from_a(&s));
            b += usize::from(from_b(&s));
        }
        assert!(
            a + b == 100 && a > 40 && b > 20,
            "weighted by length 10 : 7: {a} {b}"
        );
        let mut again = Drawn::new(&pool, model, 7, 3, 1.0, 1_000_000, 99);
        assert_eq!(steps(&mut again, 100), got);
        let mut other = Drawn::new(&pool, model, 7, 4, 1.0, 1_000_000, 99);
        assert_ne!(steps(&mut other, 100), got);
        assert_eq!(d.outcome(100).unwrap(), None, "ticks end after `last`");
    }

    /// The arrival rule: a scaled latency above the budget is a miss; a record's misses stay
    /// misses; independent draws follow the weights.
    #[test]
    fn the_budget_decides_and_independent_draws_follow_the_weights() {
        let src = Source {
            path: "h".into(),
            kind: Kind::Hgrm,
            latencies: Latencies::Histogram(vec![(10_000, 3), (100_000, 1)]),
            laws: vec![],
            ticks: 4,
            recorded: None,
        };
        let e = Pool::new(&mut [src.clone()], Model::Block { ticks: 10 })
            .err()
            .unwrap()
            .to_string();
        assert!(e.contains("--draw independent"), "{e}");
        let pool = Pool::new(
            &mut [src, seq_source(vec![vec![ReplyOutcome::Missed]])],
            Model::Independent,
        )
        .unwrap();
        let mut d = Drawn::new(&pool, Model::Independent, 1, 0, 2.0, 150_000, 19_999);
        let got = steps(&mut d, 20_000);
        let count = |s: ReplyOutcome| got.iter().filter(|&&x| x == s).count() as f64 / 20_000.0;
        assert!((count(ReplyOutcome::Applied(20_000)) - 0.6).abs() < 0.02);
        // 100 µs × 2 = 200 µs > 150 µs: late.
        assert!((count(ReplyOutcome::Late) - 0.2).abs() < 0.02);
        assert!((count(ReplyOutcome::Missed) - 0.2).abs() < 0.02);
        assert_eq!(
            d.misses,
            got.iter()
                .filter(|s| !matches!(s, ReplyOutcome::Applied(_)))
                .count() as u64
        );
    }
}
