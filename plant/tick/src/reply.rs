//! What became of the controller's reply to one tick, declared once: [`ReplyOutcome`]. Its fate
//! alone ([`ReplyFate`], the word of `trace.csv`'s `reply` column) is derived from it, and what
//! reached the plant ([`Arrival`]: the torque, or nothing) is made from it by
//! [`ReplyOutcome::arrival`]. A new outcome is one variant here; the compiler then points at
//! every match that must take it (these conversions, the in-process loop, the what-if draws).

use deltaloop_wire::TorqueMsg;

/// What became of the controller's reply to tick k, as the in-process loop steps it (an arrival
/// schedule: ideal, replayed from a trace, drawn by the what-if) and as a record tells it. The
/// declaration order is the sort order (`Ord`): applied replies by latency, then late, skipped,
/// missed.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, strum::EnumDiscriminants)]
#[cfg_attr(test, derive(strum::EnumIter))]
#[strum_discriminants(
    name(ReplyFate),
    derive(Hash, serde::Serialize, serde::Deserialize, strum::IntoStaticStr, strum::VariantArray),
    serde(rename_all = "snake_case"),
    strum(serialize_all = "snake_case"),
    // strum passes on only attributes with parentheses: the doc rides in an always-on cfg_attr.
    cfg_attr(
        all(),
        doc = "What became of the controller's reply to tick k (`trace.csv` column `reply`): a \
               [`ReplyOutcome`] without its latency."
    )
)]
pub enum ReplyOutcome {
    /// It arrived in time and went to the drives (which may still clamp or reject it), this many
    /// ns after its tick's deadline t_k + D (D: the configured transport delay).
    Applied(u64),
    /// The controller answered after the torque budget: dropped, the drives held.
    Late,
    /// The controller never answered this state: it answered a newer one instead.
    Skipped,
    /// No answer at all: the drives held.
    Missed,
}

deltaloop_names::text_words!("reply"; ReplyFate);

impl ReplyFate {
    /// The outcome of this fate; an applied reply reaches the drives `applied_after_ns` after
    /// t_k + D (a fate without a reply ignores it).
    pub fn outcome(self, applied_after_ns: u64) -> ReplyOutcome {
        match self {
            ReplyFate::Applied => ReplyOutcome::Applied(applied_after_ns),
            ReplyFate::Late => ReplyOutcome::Late,
            ReplyFate::Skipped => ReplyOutcome::Skipped,
            ReplyFate::Missed => ReplyOutcome::Missed,
        }
    }

    /// The outcome of a recorded reply: its fate and `arrival_ns` (A_k − t_k, ns, as `trace.csv`
    /// and the telemetry count it, from t_k) less the transport delay `delay_ns` D (the plant
    /// counts from t_k + D, and adds D back). An applied reply without its arrival (the row the
    /// divergence rule ended a run on) reaches the drives at once.
    pub fn recorded(self, arrival_ns: Option<u64>, delay_ns: u64) -> ReplyOutcome {
        self.outcome(arrival_ns.map_or(0, |a| a.saturating_sub(delay_ns)))
    }
}

impl ReplyOutcome {
    /// The fate alone.
    pub fn fate(self) -> ReplyFate {
        self.into()
    }

    /// What reaches the plant when the controller's reply is `reply`: an applied reply at its
    /// latency; anything else holds the drives.
    pub fn arrival(self, reply: TorqueMsg) -> Arrival {
        match self {
            ReplyOutcome::Applied(ns) => Arrival::ReplyAfter(reply, ns),
            ReplyOutcome::Late | ReplyOutcome::Skipped | ReplyOutcome::Missed => Arrival::Missed,
        }
    }
}

/// What reached the plant for the current tick: the plant's side of a [`ReplyOutcome`] (made by
/// [`ReplyOutcome::arrival`]; the process modes make it from the reply they took), with the
/// torque and without what the plant cannot tell apart (late, skipped and missed all hold).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Arrival {
    /// The controller's reply to this tick, in time, reaching the drives at its tick (plus the
    /// configured transport delay): `ReplyAfter(reply, 0)`.
    Reply(TorqueMsg),
    /// The reply, in time, reaching the drives a measured latency (ns) after its tick's deadline
    /// (plus the configured transport delay): realtime with `apply_torque = "arrival"`, and the
    /// in-process loop over an arrival schedule.
    ReplyAfter(TorqueMsg, u64),
    /// No reply in time: the drives hold the last applied torque.
    Missed,
}

impl Arrival {
    /// The applied torque and its latency after the tick's deadline, ns; None: the drives hold.
    pub fn reply(self) -> Option<(TorqueMsg, u64)> {
        match self {
            Arrival::Reply(t) => Some((t, 0)),
            Arrival::ReplyAfter(t, latency) => Some((t, latency)),
            Arrival::Missed => None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use strum::IntoEnumIterator;

    /// Every outcome goes to its fate and back, and every fate to its outcome and back, through
    /// the one exhaustive list of each (strum's `EnumIter`, `VariantArray`): an outcome added
    /// with a conversion that maps it onto another fails here.
    #[test]
    fn every_outcome_round_trips_through_its_fate() {
        for o in ReplyOutcome::iter() {
            let o = match o {
                ReplyOutcome::Applied(_) => ReplyOutcome::Applied(1_234),
                other => other,
            };
            assert_eq!(o.fate().outcome(1_234), o, "{o:?}");
            assert_eq!(ReplyFate::parse(o.fate().name()), Ok(o.fate()));
        }
        for &f in ReplyFate::ALL {
            assert_eq!(f.outcome(7).fate(), f, "{f:?}");
        }
        assert_eq!(ReplyOutcome::iter().count(), ReplyFate::ALL.len());
    }

    /// Only an applied reply reaches the drives, at its latency; a recorded arrival is taken
    /// less the transport delay, saturating at 0.
    #[test]
    fn only_an_applied_reply_arrives_and_a_recorded_one_less_the_delay() {
        let t = TorqueMsg::default();
        for o in ReplyOutcome::iter() {
            let a = o.arrival(t).reply();
            match o {
                ReplyOutcome::Applied(ns) => assert_eq!(a, Some((t, ns))),
                _ => assert_eq!(a, None, "{o:?}"),
            }
        }
        assert_eq!(Arrival::Reply(t).reply(), Arrival::ReplyAfter(t, 0).reply());
        let d = 50_000;
        assert_eq!(
            ReplyFate::Applied.recorded(Some(80_000), d),
            ReplyOutcome::Applied(30_000)
        );
        assert_eq!(
            ReplyFate::Applied.recorded(Some(10), d),
            ReplyOutcome::Applied(0)
        );
        assert_eq!(
            ReplyFate::Applied.recorded(None, d),
            ReplyOutcome::Applied(0)
        );
        assert_eq!(
            ReplyFate::Late.recorded(Some(80_000), d),
            ReplyOutcome::Late
        );
    }

    /// The words of `trace.csv`'s `reply` column.
    #[test]
    fn fates_have_the_trace_words() {
        assert_eq!(
            deltaloop_names::allowed::<ReplyFate>(),
            "applied, late, skipped, missed"
        );
        assert_eq!(ReplyFate::Skipped.to_string(), "skipped");
    }
}
