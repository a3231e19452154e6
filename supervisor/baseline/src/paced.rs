//! Ping-pongs at the loop's rate: one state-sized message each way per period Ts, the round trip
//! of each timed on one clock (CLOCK_MONOTONIC, the pinging thread's). What a transport costs a
//! loop that runs at 3.3 kHz, not at its own top speed (a waiting side blocks between periods,
//! as a realtime loop's does). `bench ros2` compares DDS with these.

use anyhow::{Context, Result, bail};
use deltaloop_study::latency_histogram;
use deltaloop_transport::ipc::{self, IpcContext};
use deltaloop_transport::rt;
use deltaloop_transport::wire::{StateMsg, TorqueMsg};
use hdrhistogram::Histogram;
use std::net::UdpSocket;
use std::time::Duration;

/// How long a ping waits for its pong before it counts it lost.
pub const PONG_TIMEOUT: Duration = Duration::from_millis(100);

/// Round trips of one ping-pong.
pub struct PingPong {
    /// Round trip, ns.
    pub rtt: Histogram<u64>,
    /// Pings whose pong did not come within [`PONG_TIMEOUT`].
    pub lost: u64,
    pub count: u64,
}

impl PingPong {
    /// The round trip at quantile `q`, µs.
    pub fn us(&self, q: f64) -> f64 {
        self.rtt.value_at_quantile(q) as f64 / 1e3
    }
}

/// Unrecorded round trips first: the two sides connect and warm up.
const WARM_UP: u64 = 50;

/// `count` round trips, one every `period_ns` (after [`WARM_UP`] unrecorded ones numbered from
/// 2^62): `round(seq)` sends ping `seq` and waits for its pong (false: it did not come).
pub fn paced(
    count: u64,
    period_ns: u64,
    mut round: impl FnMut(u64) -> Result<bool>,
) -> Result<PingPong> {
    let mut out = PingPong {
        rtt: latency_histogram(),
        lost: 0,
        count,
    };
    for i in 0..WARM_UP {
        rt::sleep_until_ns(rt::now_ns() + period_ns);
        round((1 << 62) + i)?;
    }
    let t0 = rt::now_ns() + 10 * period_ns;
    for seq in 0..count {
        rt::sleep_until_ns(t0 + seq * period_ns);
        let sent = rt::now_ns();
        if round(seq)? {
            let _ = out.rtt.record((rt::now_ns() - sent).max(1));
        } else {
            out.lost += 1;
        }
    }
    Ok(out)
}

/// UDP on loopback, both sides blocking in `recv` (the link's transport, without its sealing).
pub fn udp(count: u64, period_ns: u64) -> Result<PingPong> {
    let pong = UdpSocket::bind("127.0.0.1:0").context("bind the pong socket")?;
    let ping = UdpSocket::bind("127.0.0.1:0").context("bind the ping socket")?;
    ping.connect(pong.local_addr()?)?;
    ping.set_read_timeout(Some(PONG_TIMEOUT))?;
    pong.set_read_timeout(Some(Duration::from_secs(2)))?;
    let echo = std::thread::spawn(move || -> Result<()> {
        let mut buf = [0u8; 512];
        loop {
            let (n, from) = match pong.recv_from(&mut buf) {
                Ok(r) => r,
                Err(_) => return Ok(()), // the ping ended: silence
            };
            pong.send_to(&buf[..n], from)?;
        }
    });
    let mut buf = [0u8; size_of::<StateMsg>()];
    let mut back = [0u8; 512];
    let r = paced(count, period_ns, |seq| {
        buf[..8].copy_from_slice(&seq.to_le_bytes());
        ping.send(&buf)?;
        loop {
            match ping.recv(&mut back) {
                Ok(n) if n >= 8 && back[..8] == seq.to_le_bytes() => return Ok(true),
                Ok(_) => continue, // a late pong of an earlier ping
                Err(_) => return Ok(false),
            }
        }
    });
    let _ = echo.join();
    r
}

/// iceoryx2 on this host, the loop's own state and torque services and wake-up events, both
/// sides blocking on the event (the default realtime hand-off).
pub fn iox(count: u64, period_ns: u64) -> Result<PingPong> {
    let run_id = ipc::new_run_id();
    let (ready_tx, ready_rx) = std::sync::mpsc::channel::<Result<()>>();
    let id = run_id.clone();
    let echo = std::thread::spawn(move || -> Result<()> {
        let node = ipc::node("bench-pong", &id)?;
        let state = ipc::state(&node, &id)?.subscriber(None, "state subscriber")?;
        let torque = ipc::torque(&node, &id)?.publisher("torque publisher")?;
        let woken = ipc::listener(&node, &id, "state-ready")?;
        let wake = ipc::notifier(&node, &id, "torque-ready")?;
        let _ = ready_tx.send(Ok(()));
        loop {
            match state.receive().ipc("receive state")? {
                Some(s) if s.tick == u64::MAX => return Ok(()),
                Some(s) => {
                    torque
                        .send_copy(TorqueMsg {
                            tick: s.tick,
                            ..TorqueMsg::default()
                        })
                        .ipc("publish torque")?;
                    wake.notify().ipc("notify torque")?;
                }
                None => {
                    if woken.timed_wait(Duration::from_secs(2)).is_err() {
                        return Ok(());
                    }
                }
            }
        }
    });
    ready_rx
        .recv_timeout(Duration::from_secs(10))
        .context("the iceoryx2 pong did not start")??;
    let node = ipc::node("bench-ping", &run_id)?;
    let state = ipc::state(&node, &run_id)?.publisher("state publisher")?;
    let torque = ipc::torque(&node, &run_id)?.subscriber(None, "torque subscriber")?;
    let wake = ipc::notifier(&node, &run_id, "state-ready")?;
    let woken = ipc::listener(&node, &run_id, "torque-ready")?;
    ipc::connect_now(&[&state, &torque])?;
    let r = paced(count, period_ns, |seq| {
        state
            .send_copy(StateMsg {
                tick: seq,
                ..StateMsg::default()
            })
            .ipc("publish state")?;
        wake.notify().ipc("notify state")?;
        let until = rt::now_ns() + PONG_TIMEOUT.as_nanos() as u64;
        loop {
            while let Some(t) = torque.receive().ipc("receive torque")? {
                if t.tick == seq {
                    return Ok(true);
                }
            }
            let now = rt::now_ns();
            if now >= until {
                return Ok(false);
            }
            let _ = woken.timed_wait(Duration::from_nanos(until - now));
        }
    });
    let _ = state.send_copy(StateMsg {
        tick: u64::MAX,
        ..StateMsg::default()
    });
    let _ = wake.notify();
    match echo.join() {
        Ok(e) => e?,
        Err(_) => bail!("the iceoryx2 pong panicked"),
    }
    r
}
