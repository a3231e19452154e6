//! What a near bridge tells the supervisor of a run's link, in `link-<run id>.json`.

use std::path::Path;

/// What the near bridge tells the supervisor about a run's link, in `link-<run id>.json` next to
/// the run's config: who joined, with which key (its fingerprint, never the key), and what the
/// link refused, on each host.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct LinkReport {
    /// The far side's address (TCP), as this host saw it.
    pub peer: String,
    /// [`LinkKey::fingerprint`] of the link key.
    pub key_fingerprint: String,
    /// Connections refused before the far side joined: wrong key, silence or slowness, or no
    /// room (one not yet proven dropped for a newer one).
    pub refused_connections: u64,
    /// Datagrams refused during the run, by reason: both hosts together (`near` + `far`).
    pub refused_datagrams: RefusedCounts,
    /// Errors reported by ICMP on the link's UDP sockets during the run (port, host or network
    /// unreachable), both hosts together: each held back a datagram, which was sent again.
    #[serde(default)]
    pub icmp_errors: u64,
    /// What the near side (the supervisor's host) refused.
    #[serde(default)]
    pub near: SideRefusals,
    /// What the far side (`join`'s host) refused, as it reported at the end of the run; None if
    /// it did not report (the link went down first).
    #[serde(default)]
    pub far: Option<SideRefusals>,
}

/// What one side of the link refused during a run.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct SideRefusals {
    /// Datagrams refused, by reason.
    pub refused_datagrams: RefusedCounts,
    /// Errors reported by ICMP on this side's UDP socket (see [`LinkReport::icmp_errors`]).
    #[serde(default)]
    pub icmp_errors: u64,
}

impl SideRefusals {
    /// Bytes of a `Refused` frame: the counts by reason, then the ICMP errors (u64 LE).
    pub const WIRE: usize = RefusedCounts::WIRE + 8;

    pub fn to_wire(self) -> [u8; Self::WIRE] {
        let mut b = [0u8; Self::WIRE];
        b[..RefusedCounts::WIRE].copy_from_slice(&self.refused_datagrams.to_wire());
        b[RefusedCounts::WIRE..].copy_from_slice(&self.icmp_errors.to_le_bytes());
        b
    }

    /// A `Refused` frame's (None: not [`Self::WIRE`] bytes).
    pub fn from_wire(b: &[u8]) -> Option<Self> {
        if b.len() != Self::WIRE {
            return None;
        }
        let (counts, icmp) = b.split_at(RefusedCounts::WIRE);
        let mut w = [0u8; 8];
        w.copy_from_slice(icmp);
        Some(Self {
            refused_datagrams: RefusedCounts::from_wire(counts)?,
            icmp_errors: u64::from_le_bytes(w),
        })
    }
}

/// Datagrams refused, by reason (the link's `Refusals` by name), for JSON.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct RefusedCounts {
    pub malformed: u64,
    pub other_run: u64,
    pub forged: u64,
    pub replayed: u64,
}

impl RefusedCounts {
    /// Bytes of the counts on the wire (a `Refused` frame).
    pub const WIRE: usize = 32;

    /// All reasons together. Saturating, as [`Self::plus`]: the far side's counts are what it
    /// sent, any u64.
    pub fn total(&self) -> u64 {
        [self.other_run, self.forged, self.replayed]
            .iter()
            .fold(self.malformed, |t, n| t.saturating_add(*n))
    }

    /// Both sides' counts together (saturating: the far side's are what it sent).
    pub fn plus(self, o: Self) -> Self {
        Self {
            malformed: self.malformed.saturating_add(o.malformed),
            other_run: self.other_run.saturating_add(o.other_run),
            forged: self.forged.saturating_add(o.forged),
            replayed: self.replayed.saturating_add(o.replayed),
        }
    }

    /// `forged 3, replayed 1`; empty when none.
    pub fn describe(&self) -> String {
        [
            ("malformed", self.malformed),
            ("other run", self.other_run),
            ("forged", self.forged),
            ("replayed", self.replayed),
        ]
        .iter()
        .filter(|(_, n)| *n > 0)
        .map(|(r, n)| format!("{r} {n}"))
        .collect::<Vec<_>>()
        .join(", ")
    }

    /// The counts as a `Refused` frame carries them: four u64, little-endian.
    pub fn to_wire(self) -> [u8; Self::WIRE] {
        let mut b = [0u8; Self::WIRE];
        for (i, n) in [self.malformed, self.other_run, self.forged, self.replayed]
            .iter()
            .enumerate()
        {
            b[8 * i..8 * i + 8].copy_from_slice(&n.to_le_bytes());
        }
        b
    }

    /// The counts of a `Refused` frame (None: not [`Self::WIRE`] bytes).
    pub fn from_wire(b: &[u8]) -> Option<Self> {
        if b.len() != Self::WIRE {
            return None;
        }
        let n = |i: usize| {
            let mut w = [0u8; 8];
            w.copy_from_slice(&b[8 * i..8 * i + 8]);
            u64::from_le_bytes(w)
        };
        Some(Self {
            malformed: n(0),
            other_run: n(1),
            forged: n(2),
            replayed: n(3),
        })
    }
}

impl LinkReport {
    /// Where the near bridge of run `run_id` writes it: next to the run's `config`.
    pub fn path(config: &Path, run_id: &str) -> std::path::PathBuf {
        config.with_file_name(format!("link-{run_id}.json"))
    }

    /// Writes it to `path` (a new private file).
    pub fn write(&self, path: &Path) -> Result<(), String> {
        let text = serde_json::to_string_pretty(self).map_err(|e| e.to_string())?;
        let _ = std::fs::remove_file(path);
        crate::files::create_private(path, text.as_bytes())
            .map_err(|e| format!("cannot write {}: {e}", path.display()))
    }

    /// Reads one (None if there is none, or it is not one).
    pub fn read(path: &Path) -> Option<Self> {
        let b = crate::files::read_no_follow(path).ok()?;
        serde_json::from_slice(&b).ok()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Regression: the counts of a REFUSED frame are whatever the far side sent, and adding them
    /// (both hosts' together, the total) overflowed and panicked the near bridge. They saturate.
    #[test]
    fn regression_refused_counts_from_the_far_side_cannot_overflow() {
        let max = RefusedCounts::from_wire(&[0xff; RefusedCounts::WIRE]).unwrap();
        assert_eq!(max.total(), u64::MAX);
        let near = RefusedCounts {
            forged: 3,
            ..RefusedCounts::default()
        };
        let both = near.plus(max);
        assert_eq!((both.forged, both.malformed), (u64::MAX, u64::MAX));
        assert_eq!(both.total(), u64::MAX);
        assert!(both.describe().contains(&format!("forged {}", u64::MAX)));
    }

    /// Regression: ICMP errors on the link's sockets were neither counted nor reported (the
    /// run's `link_security` said nothing while they dropped 40 % of the ticks). Each side's
    /// count crosses in its REFUSED frame and is in the report; a report of a run before them
    /// still reads.
    #[test]
    fn regression_icmp_errors_cross_the_link_and_are_in_the_report() {
        let far = SideRefusals {
            refused_datagrams: RefusedCounts {
                replayed: 2,
                ..RefusedCounts::default()
            },
            icmp_errors: 4321,
        };
        assert_eq!(SideRefusals::from_wire(&far.to_wire()), Some(far));
        assert_eq!(SideRefusals::from_wire(&far.to_wire()[1..]), None);
        let r = LinkReport {
            icmp_errors: 4321,
            far: Some(far),
            ..LinkReport::default()
        };
        let json = serde_json::to_string(&r).unwrap();
        assert!(json.contains("\"icmp_errors\":4321"), "{json}");
        let old = r#"{"peer":"p","key_fingerprint":"k","refused_connections":0,"refused_datagrams":{"malformed":0,"other_run":0,"forged":0,"replayed":0}}"#;
        let old: LinkReport = serde_json::from_str(old).unwrap();
        assert_eq!(old.icmp_errors, 0);
    }
}
