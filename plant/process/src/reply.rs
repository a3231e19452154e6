//! A torque reply while the plant waits for it: judged by the controller's trusted send time
//! ([`reply_verdict`], [`trusted_stamp`]), and the wait for tick k's ([`wait_torque`]), over the
//! loop's transport.

use crate::{Physics, PlantSide};
use anyhow::Result;
use deltaloop_config::Poll;
use deltaloop_transport::exchange::PlantTransport;
use deltaloop_transport::ipc::ControlIn;
use deltaloop_transport::rt;
use deltaloop_transport::wire::{ControlKind, Sender, TorqueMsg};

/// What the plant does with a torque reply while it waits for tick `tick`'s.
#[derive(Debug, PartialEq, Eq)]
enum Reply {
    /// The answer to this tick, sent within the budget.
    Apply,
    /// Too late: for an earlier tick, or for this one but sent after the budget ended.
    Late,
    /// Not an answer to any state published yet (a misbehaving peer): dropped.
    Ignore,
}

/// Judges a reply by the controller's own send time (`stamp_ns`, from [`trusted_stamp`]), not by
/// when the plant looks: a plant that was itself preempted past the budget must not apply a reply
/// that came late (it would count a late controller as on time, and the miss statistics would
/// depend on the plant's CPU).
fn reply_verdict(m: &TorqueMsg, stamp_ns: u64, tick: u64, until_ns: u64) -> Reply {
    match m.tick.cmp(&tick) {
        std::cmp::Ordering::Equal if stamp_ns <= until_ns => Reply::Apply,
        std::cmp::Ordering::Equal | std::cmp::Ordering::Less => Reply::Late,
        std::cmp::Ordering::Greater => Reply::Ignore,
    }
}

/// The controller's publish stamp `claimed` if it can be true, else the plant's own receive time
/// `rx_ns` (all CLOCK_MONOTONIC, ns); true when it was replaced. A reply cannot have been sent
/// before the state it answers was published (`state_pub_ns`) nor after the plant received it:
/// a stamp outside that window is a peer's lie (regression: a controller that stamped its replies
/// with the state's deadline, or 0, was charged no latency and never missed its budget), and the
/// physics then rests on what the plant itself observed.
fn trusted_stamp(claimed: u64, state_pub_ns: u64, rx_ns: u64) -> (u64, bool) {
    if (state_pub_ns..=rx_ns).contains(&claimed) {
        (claimed, false)
    } else {
        (rx_ns, true)
    }
}

/// A reply the plant applies.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Received {
    pub(crate) msg: TorqueMsg,
    /// When the plant took it, ns.
    pub(crate) rx_ns: u64,
    /// When it was published, as far as the plant can trust the controller's stamp, ns.
    pub(crate) stamp_ns: u64,
    /// The controller's stamp was impossible and replaced by `rx_ns`.
    pub(crate) stamp_replaced: bool,
}

/// How the wait for a reply ended.
pub(crate) enum Awaited {
    Reply(Received),
    /// No reply by the end of the wait.
    Nothing,
    /// The controller said its step failed (CONTROLLER_ERROR): no reply will come. One line.
    ControllerError(String),
}

/// Waits for τ_k until `until_ns`: polls (spinning or yielding, `poll`) until `poll_until_ns`
/// (what the state declared), then blocks on the transport's wake-ups. The clock is read before
/// each look, so the look that precedes blocking happens at or after `poll_until_ns`
/// (docs/protocol.md §6.1). Replies judged late (for earlier ticks: copies that came late, too)
/// are dropped and counted on `side`; replies for later ticks are ignored. `state_pub_ns` is when
/// state `tick` was published. Before each block, and when the wait ends empty, it looks for the
/// controller's CONTROLLER_ERROR on `from_controller` (the controller, or the bridge standing in
/// for it, wakes the plant after sending it).
pub(crate) fn wait_torque<P: Physics, T: PlantTransport>(
    link: &mut T,
    from_controller: &ControlIn,
    tick: u64,
    (state_pub_ns, poll_until_ns, until_ns): (u64, u64, u64),
    poll: Poll,
    side: &mut PlantSide<P>,
) -> Result<Awaited> {
    // Whether the last block saw a wake-up event (a transport may drain only then).
    let mut woke = false;
    loop {
        let now = rt::now_ns();
        let (mut got, mut late) = (None, 0u64);
        link.take_replies(|m| {
            // The plant takes the reply now: the round trip counts to now.
            let rx_ns = rt::now_ns();
            let (stamp_ns, stamp_replaced) = trusted_stamp(m.t_publish_ns, state_pub_ns, rx_ns);
            match reply_verdict(&m, stamp_ns, tick, until_ns) {
                Reply::Apply if got.is_none() => {
                    got = Some(Received {
                        msg: m,
                        rx_ns,
                        stamp_ns,
                        stamp_replaced,
                    })
                }
                Reply::Apply | Reply::Ignore => {}
                Reply::Late => late += 1,
            }
            got.is_some()
        })?;
        for _ in 0..late {
            side.late_reply();
        }
        if let Some(r) = got {
            return Ok(Awaited::Reply(r));
        }
        if now >= until_ns {
            return Ok(controller_error(from_controller)
                .map_or(Awaited::Nothing, Awaited::ControllerError));
        }
        if now < poll_until_ns {
            rt::poll_pause(poll);
            continue;
        }
        if !link.settle(std::mem::take(&mut woke))? {
            continue;
        }
        if let Some(why) = controller_error(from_controller) {
            return Ok(Awaited::ControllerError(why));
        }
        woke = link.block(now, until_ns)?;
    }
}

/// The controller's CONTROLLER_ERROR, if it sent one, as the plant's cause: which tick, and the
/// error it quoted. Only the controller can publish on its service (one publisher slot, checked
/// by the supervisor); its other kinds are not for the plant.
fn controller_error(sub: &ControlIn) -> Option<String> {
    while let Ok(Some(m)) = sub.receive() {
        if m.kind() == Some(ControlKind::ControllerError) && m.sender() == Some(Sender::Controller)
        {
            return Some(format!(
                "the controller reported an error at tick {}: {}",
                m.tick,
                m.text()
            ));
        }
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    fn reply(tick: u64, t_publish_ns: u64) -> TorqueMsg {
        TorqueMsg {
            tick,
            t_publish_ns,
            ..TorqueMsg::default()
        }
    }

    fn verdict(m: &TorqueMsg, tick: u64, until_ns: u64) -> Reply {
        reply_verdict(m, m.t_publish_ns, tick, until_ns)
    }

    #[test]
    fn a_reply_in_budget_for_this_tick_is_applied() {
        assert_eq!(verdict(&reply(7, 1_000), 7, 1_000), Reply::Apply);
        assert_eq!(verdict(&reply(7, 999), 7, 1_000), Reply::Apply);
    }

    /// Regression: the plant took the controller's publish stamp as the arrival time, so a slow
    /// controller that stamped its replies with the state's deadline (or 0) was charged zero
    /// latency and never missed its budget. A stamp outside [state published, reply received]
    /// is replaced by the plant's own receive time, and the tick says so.
    #[test]
    fn regression_a_forged_publish_stamp_is_replaced_by_the_plants_receive_time() {
        // State published at 1 000, reply received at 1 400.
        assert_eq!(trusted_stamp(1_200, 1_000, 1_400), (1_200, false));
        assert_eq!(trusted_stamp(1_000, 1_000, 1_400), (1_000, false));
        assert_eq!(trusted_stamp(1_400, 1_000, 1_400), (1_400, false));
        // The deadline (before the state was published), 0, or the future: not believed.
        assert_eq!(trusted_stamp(900, 1_000, 1_400), (1_400, true));
        assert_eq!(trusted_stamp(0, 1_000, 1_400), (1_400, true));
        assert_eq!(trusted_stamp(5_000, 1_000, 1_400), (1_400, true));
        // A reply received after the budget with a stamp of 0 is late, not applied.
        let (stamp, _) = trusted_stamp(0, 1_000, 1_400);
        assert_eq!(reply_verdict(&reply(7, 0), stamp, 7, 1_150), Reply::Late);
    }

    /// Regression: a plant preempted past its budget applied the late reply it found on waking,
    /// so a controller 1 ms late was counted on time whenever the plant's CPU was busy (seen as a
    /// flaky compute-delay test without SCHED_FIFO).
    #[test]
    fn regression_reply_sent_after_the_budget_is_late_even_if_the_plant_sees_it_late_too() {
        assert_eq!(verdict(&reply(7, 1_001), 7, 1_000), Reply::Late);
    }

    #[test]
    fn replies_for_earlier_ticks_are_late_and_for_later_ticks_ignored() {
        assert_eq!(verdict(&reply(6, 10), 7, 1_000), Reply::Late);
        assert_eq!(verdict(&reply(8, 10), 7, 1_000), Reply::Ignore);
    }
}
