//! A sweep as a plan: every point in the canonical expansion order, with an id that is the same
//! on any machine and in any order of execution, and which points a shard runs.
//!
//! - **Point id**: `<index>-<hash>`, the point's index in the expansion order (scenario, preset,
//!   law, then ℓ × d, then the sub-tick, compute-delay and link-delay side axes), zero-padded to 4
//!   digits, and the first 8 hex digits of the SHA-256 of its parameters (scenario, preset, law,
//!   ℓ, d, D, the compute delay, the loop mode and a link point's emulated link). The index
//!   sorts; the hash catches a row that claims the index of another point.
//! - **Plan hash**: the SHA-256 of the sweep file as parsed (every key but the path of `base`) and
//!   of the resolved base config. Two copies of the same sweep (another machine, another folder, a
//!   copy shipped to a cluster worker) have the same hash; a changed axis or base constant does
//!   not.

use super::{Job, SweepFile, jobs, point_config};
use anyhow::{Context, Result, bail};
use deltaloop_config::{LoopMode, RunConfig};
use serde::Serialize;
use sha2::{Digest, Sha256};

/// One point of the plan.
#[derive(Debug, Clone)]
pub struct Point {
    /// Position in the canonical expansion order, from 0.
    pub index: usize,
    /// `<index>-<hash>` (see the module doc).
    pub id: String,
    /// Its parameters (scenario, preset, law, ℓ, d and a side axis's value), as [`Point::label`]
    /// shows them.
    pub job: Job,
    /// The loop mode it runs in.
    pub mode: LoopMode,
}

impl Point {
    /// Whole CPUs the point occupies while it runs: a realtime point holds the plant's and the
    /// controller's cores for its whole duration; an inproc or lockstep point keeps one busy
    /// (lockstep's two processes take turns).
    pub fn cpus(&self) -> u32 {
        if self.mode == LoopMode::Realtime {
            2
        } else {
            1
        }
    }

    /// `s1/matched/tdc ℓ=1 d=0` and the side axes.
    pub fn label(&self) -> String {
        self.job.to_string()
    }
}

/// A loaded sweep with its points.
#[derive(Debug, Clone)]
pub struct Plan {
    pub sweep: SweepFile,
    pub base: RunConfig,
    /// SHA-256, hex (see the module doc).
    pub hash: String,
    pub points: Vec<Point>,
}

fn sha256_hex(parts: &[&[u8]]) -> String {
    let mut h = Sha256::new();
    for p in parts {
        // Length-prefixed, so no two different part lists hash alike.
        h.update((p.len() as u64).to_le_bytes());
        h.update(p);
    }
    format!("{:x}", h.finalize())
}

/// The parameters a point id hashes. `D` is written exactly (Rust's shortest round-trip form);
/// a link point adds its emulated link, a compensated law its `+pred` (the other points' ids
/// stay as they were).
fn params_key(job: &Job, mode: LoopMode) -> String {
    let mut key = format!(
        "scenario={} preset={} law={} ell={} d={} D_us={:?} compute_us={} mode={}",
        job.scenario.name(),
        job.preset.name(),
        job.variant(),
        job.ell,
        job.d,
        job.kind.transport_us(),
        job.kind.compute_us(),
        mode.name()
    );
    if let Some(l) = job.kind.link() {
        key += &format!(
            " link_delay_us={:?} link_jitter_us={:?} link_loss={:?}",
            l.delay_us, l.jitter_us, l.loss
        );
    }
    key
}

impl Plan {
    /// Expands `sweep` over `base` and checks the sweep's keys (the points' configs are checked
    /// by [`Plan::check_points`], for the points that run).
    pub fn new(sweep: SweepFile, base: RunConfig) -> Result<Self> {
        let mut points = Vec::new();
        for (index, job) in jobs(&sweep)?.into_iter().enumerate() {
            let mode = if job.kind.realtime() {
                LoopMode::Realtime
            } else {
                sweep.mode
            };
            let h = sha256_hex(&[params_key(&job, mode).as_bytes()]);
            points.push(Point {
                index,
                id: format!("{index:04}-{}", &h[..8]),
                job,
                mode,
            });
        }
        let mut hashed = sweep.clone();
        hashed.base = Default::default();
        let hash = sha256_hex(&[
            b"deltaloop sweep plan 1",
            serde_json::to_string(&hashed)?.as_bytes(),
            base.to_toml_string().as_bytes(),
        ]);
        Ok(Plan {
            sweep,
            base,
            hash,
            points,
        })
    }

    /// Checks that the points `indices` are valid configs; the first that is not is the error.
    pub fn check_points(&self, indices: &[usize]) -> Result<()> {
        for &i in indices {
            let job = &self.points[i].job;
            point_config(&self.base, job).with_context(|| format!("sweep point {job}"))?;
        }
        Ok(())
    }

    /// The first 12 hex digits of the plan hash, for messages.
    pub fn short_hash(&self) -> &str {
        &self.hash[..12]
    }

    /// The index of the point with this id.
    pub fn find(&self, id: &str) -> Option<usize> {
        let i: usize = id.split_once('-')?.0.parse().ok()?;
        self.points.get(i).filter(|p| p.id == id).map(|p| p.index)
    }

    /// The plan as `deltaloop sweep plan --json` prints it: what a cluster driver needs to run
    /// it elsewhere (the sweep and base as TOML text, the points and what each needs).
    pub fn to_json(&self, sweep_file: &str) -> Result<String> {
        #[derive(Serialize)]
        struct P<'a> {
            index: usize,
            id: &'a str,
            label: String,
            mode: LoopMode,
            cpus: u32,
        }
        #[derive(Serialize)]
        struct J<'a> {
            name: &'a str,
            sweep_file: &'a str,
            plan_hash: &'a str,
            sweep_toml: String,
            base_toml: String,
            points: Vec<P<'a>>,
        }
        Ok(serde_json::to_string_pretty(&J {
            name: &self.sweep.name,
            sweep_file,
            plan_hash: &self.hash,
            sweep_toml: toml::to_string_pretty(&self.sweep)?,
            base_toml: self.base.to_toml_string(),
            points: self
                .points
                .iter()
                .map(|p| P {
                    index: p.index,
                    id: &p.id,
                    label: p.label(),
                    mode: p.mode,
                    cpus: p.cpus(),
                })
                .collect(),
        })?)
    }

    /// The plan as a table (`deltaloop sweep plan`).
    pub fn to_text(&self, sweep_file: &str) -> String {
        use std::fmt::Write as _;
        let mut s = format!(
            "# sweep {} ({sweep_file}): {} points, plan {}\n# id             cpus  mode      point\n",
            self.sweep.name,
            self.points.len(),
            self.hash
        );
        for p in &self.points {
            let _ = writeln!(
                s,
                "{:<16} {:<5} {:<9} {}",
                p.id,
                p.cpus(),
                p.mode.name(),
                p.label()
            );
        }
        s
    }
}

/// Which points of a plan a shard runs.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Selection {
    All,
    /// Indices as given with `--points`: `120-239`, `3,7,10-12` (inclusive ranges).
    Points(Vec<(usize, usize)>),
    /// `--shard K/N`: the points whose index i has i mod N = K − 1 (1 ≤ K ≤ N). Striding, not
    /// blocks, spreads the costly axes (realtime points, long delays) evenly over the shards.
    Shard {
        k: usize,
        n: usize,
    },
}

impl Selection {
    /// Parses a `--points` value.
    pub fn parse_points(s: &str) -> Result<Selection, String> {
        let bad = |why: &str| format!("--points {s:?}: {why}");
        let num = |t: &str| -> Result<usize, String> {
            t.trim().parse::<usize>().map_err(|_| {
                bad(&format!(
                    "{t:?} is not a point index (indices from 0, ranges like 120-239, separated by commas)"
                ))
            })
        };
        let mut ranges = Vec::new();
        for part in s.split(',') {
            let (a, b) = match part.split_once('-') {
                Some((a, b)) => (num(a)?, num(b)?),
                None => {
                    let a = num(part)?;
                    (a, a)
                }
            };
            if a > b {
                return Err(bad(&format!("range {a}-{b} is empty: write low-high")));
            }
            ranges.push((a, b));
        }
        Ok(Selection::Points(ranges))
    }

    /// Parses a `--shard` value `K/N`.
    pub fn parse_shard(s: &str) -> Result<Selection, String> {
        let bad = format!("--shard {s:?} is out of range: K/N with 1 <= K <= N, e.g. 2/16");
        let (k, n) = s.split_once('/').ok_or_else(|| bad.clone())?;
        let (k, n) = (
            k.trim().parse::<usize>().map_err(|_| bad.clone())?,
            n.trim().parse::<usize>().map_err(|_| bad.clone())?,
        );
        if !(1..=n).contains(&k) {
            return Err(bad);
        }
        Ok(Selection::Shard { k, n })
    }

    /// The selected indices of a plan of `count` points, ascending.
    pub fn indices(&self, count: usize) -> Result<Vec<usize>> {
        match self {
            Selection::All => Ok((0..count).collect()),
            Selection::Shard { k, n } => Ok((k - 1..count).step_by(*n).collect()),
            Selection::Points(ranges) => {
                let mut v = Vec::new();
                for &(a, b) in ranges {
                    if b >= count {
                        bail!(
                            "--points {}: the plan has {count} points, indices 0-{}",
                            if a == b {
                                a.to_string()
                            } else {
                                format!("{a}-{b}")
                            },
                            count.saturating_sub(1)
                        );
                    }
                    v.extend(a..=b);
                }
                v.sort_unstable();
                if let Some(w) = v.windows(2).find(|w| w[0] == w[1]) {
                    bail!("--points lists point {} twice: each at most once", w[0]);
                }
                Ok(v)
            }
        }
    }
}

/// Indices as the shortest `--points` value: `3,7-9`.
pub fn ranges_text(indices: &[usize]) -> String {
    let mut parts: Vec<String> = Vec::new();
    let mut i = 0;
    while i < indices.len() {
        let mut j = i;
        while j + 1 < indices.len() && indices[j + 1] == indices[j] + 1 {
            j += 1;
        }
        parts.push(if i == j {
            indices[i].to_string()
        } else {
            format!("{}-{}", indices[i], indices[j])
        });
        i = j + 1;
    }
    parts.join(",")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn points_and_shards_select_what_they_say() {
        let p = |s: &str| Selection::parse_points(s).unwrap().indices(10);
        assert_eq!(p("3").unwrap(), [3]);
        assert_eq!(p("7-9,0,2-3").unwrap(), [0, 2, 3, 7, 8, 9]);
        assert_eq!(
            format!("{:#}", p("8-10").unwrap_err()),
            "--points 8-10: the plan has 10 points, indices 0-9"
        );
        assert_eq!(
            format!("{:#}", p("1-4,3").unwrap_err()),
            "--points lists point 3 twice: each at most once"
        );
        for bad in ["", "a", "3-", "-3", "4-2", "1,,2", "1.5"] {
            assert!(Selection::parse_points(bad).is_err(), "{bad:?}");
        }
        // Shards are strided, cover every point once, and may be empty.
        let shard = |s: &str, n| Selection::parse_shard(s).unwrap().indices(n).unwrap();
        assert_eq!(shard("2/4", 10), [1, 5, 9]);
        let mut all: Vec<usize> = (1..=4).flat_map(|k| shard(&format!("{k}/4"), 10)).collect();
        all.sort_unstable();
        assert_eq!(all, (0..10).collect::<Vec<_>>());
        assert!(shard("16/16", 10).is_empty());
        for bad in ["0/3", "4/3", "1/0", "2", "a/b", "1/2/3"] {
            assert_eq!(
                Selection::parse_shard(bad).unwrap_err(),
                format!("--shard {bad:?} is out of range: K/N with 1 <= K <= N, e.g. 2/16")
            );
        }
        assert_eq!(ranges_text(&[0, 1, 2, 5, 7, 8]), "0-2,5,7-8");
        assert_eq!(ranges_text(&[]), "");
    }

    fn plan_of(sweep: &str, base: &str) -> Plan {
        let sw: SweepFile = toml::from_str(sweep).unwrap();
        Plan::new(sw, RunConfig::from_toml_str(base, None).unwrap()).unwrap()
    }

    const SWEEP: &str = "name = \"ids\"\nbase = \"base.toml\"\nscenarios = [\"s1\", \"s2\"]\npresets = [\"matched\"]\nlaws = [\"tdc\", \"pid\"]\ntde_delay_samples = [1, 2]\ntransport_delay_samples = [0]\ntransport_delay_us = [0, 45]\n";
    const BASE: &str = "[scenario]\npath = \"s1\"\n";

    /// Ids are index + parameter hash: the same plan gives the same ids and hash whatever the
    /// base file is called; a changed value changes the hash and the ids of the points it
    /// touches, not the others'.
    #[test]
    fn point_ids_and_plan_hash_are_stable() {
        let a = plan_of(SWEEP, BASE);
        let ids: Vec<&str> = a.points.iter().map(|p| p.id.as_str()).collect();
        assert_eq!(ids.len(), 12);
        assert!(
            ids.iter()
                .enumerate()
                .all(|(i, id)| id.starts_with(&format!("{i:04}-")) && id.len() == 13)
        );
        let b = plan_of(&SWEEP.replace("base.toml", "elsewhere/other.toml"), BASE);
        assert_eq!(a.hash, b.hash);
        assert!(a.points.iter().zip(&b.points).all(|(x, y)| x.id == y.id));
        assert_eq!(a.find(&a.points[7].id), Some(7));
        assert_eq!(a.find("0007-00000000"), None);
        // The hash of point 0 is its parameters' alone.
        let c = plan_of(&SWEEP.replace("[1, 2]", "[1, 3]"), BASE);
        assert_ne!(a.hash, c.hash);
        assert_eq!(a.points[0].id, c.points[0].id);
        assert_ne!(a.points[1].id, c.points[1].id);
        // A base constant is part of the plan, not of the ids.
        let d = plan_of(
            SWEEP,
            "[scenario]\npath = \"s1\"\n[plant]\nfriction = true\n",
        );
        assert_ne!(a.hash, d.hash);
        assert_eq!(a.points[5].id, d.points[5].id);
        // Lockstep runs the same axes in another mode: other ids.
        let e = plan_of(&format!("mode = \"lockstep\"\n{SWEEP}"), BASE);
        assert_ne!(a.points[0].id, e.points[0].id);
        // The shipped copy (as `plan --json` gives it) parses back to the same plan.
        let back = plan_of(
            &toml::to_string_pretty(&a.sweep).unwrap(),
            &a.base.to_toml_string(),
        );
        assert_eq!(back.hash, a.hash);
    }
}
