//! The DDS ping-pong of `bench ros2`: two participants of this process on loopback, a
//! JointState each way per round (reliable, the QoS of the loop's topics), the reader woken by
//! RustDDS's notification (mio), as `--controller ros2` waits. The bench paces the rounds and
//! times them (the supervisor's `bench ros2`, beside its other transports).

use crate::msg::{self, JointState, Time};
use crate::node::{Participant, Settings, Waiting, Writer, reliable, wait_matched};
use anyhow::{Context, Result, bail};
use std::time::{Duration, Instant};

const PING: &str = "/deltaloop_bench/ping";
const PONG: &str = "/deltaloop_bench/pong";

/// Waits on `r` until `until` for samples; hands each to `each`. Whether one came.
fn take(r: &mut Waiting<JointState>, until: Instant, mut each: impl FnMut(JointState)) -> bool {
    loop {
        let mut got = false;
        while let Ok(Some(s)) = r.reader.take_next_sample() {
            each(s.into_value());
            got = true;
        }
        let now = Instant::now();
        if got || now >= until {
            return got;
        }
        r.wait(until - now);
    }
}

/// The pinging side of a DDS ping-pong on one domain, this host only, with its echo in a thread
/// of its own (until two seconds pass without a ping).
pub struct Dds {
    /// Dropped first, so the echo's wait for pings ends.
    writer: Option<Writer<JointState>>,
    echo: Option<std::thread::JoinHandle<Result<()>>>,
    reader: Waiting<JointState>,
    _part: Participant,
}

impl Dds {
    /// Starts the echo on `domain` and joins it, once the two participants match (10 s at most).
    pub fn open(domain: u16) -> Result<Self> {
        let (ready_tx, ready_rx) = std::sync::mpsc::channel::<()>();
        let echo = std::thread::spawn(move || -> Result<()> {
            let p = Participant::join(Settings::localhost(domain))?;
            let w = p.writer::<JointState>("deltaloop_bench_pong", PONG, reliable(10))?;
            let mut r = Waiting::new(p.reader::<JointState>(
                "deltaloop_bench_pong",
                PING,
                reliable(10),
            )?)?;
            let _ = ready_tx.send(());
            // Until the ping ends: two seconds of silence.
            while take(&mut r, Instant::now() + Duration::from_secs(2), |m| {
                let _ = w.write(m, None);
            }) {}
            Ok(())
        });
        ready_rx
            .recv_timeout(Duration::from_secs(10))
            .context("the DDS pong did not start")?;
        let p = Participant::join(Settings::localhost(domain))?;
        let w = p.writer::<JointState>("deltaloop_bench_ping", PING, reliable(10))?;
        let r = p.reader::<JointState>("deltaloop_bench_ping", PONG, reliable(10))?;
        if wait_matched(&w, &r, Duration::from_secs(10))
            .pair()
            .is_none()
        {
            bail!("the two DDS participants did not discover each other within 10 s");
        }
        Ok(Self {
            writer: Some(w),
            echo: Some(echo),
            reader: Waiting::new(r)?,
            _part: p,
        })
    }

    /// Sends ping `seq` (a state-sized JointState) and waits up to `timeout` for its pong (false:
    /// it did not come).
    pub fn round(&mut self, seq: u64, timeout: Duration) -> Result<bool> {
        let state = msg::joint_state(seq, &[0.1; 3], &[0.2; 3], &[0.3; 3]);
        if let Some(w) = &self.writer {
            w.write(state, None)
                .map_err(|e| anyhow::anyhow!("DDS write: {e:?}"))?;
        }
        let until = Instant::now() + timeout;
        let mut back = false;
        while !back
            && take(&mut self.reader, until, |m| {
                back |= m.header.stamp == Time::of_ns(seq)
            })
        {}
        Ok(back)
    }
}

impl Drop for Dds {
    /// The ping's writer goes first; the echo then ends within its two seconds of silence.
    fn drop(&mut self) {
        drop(self.writer.take());
        if let Some(echo) = self.echo.take() {
            let _ = echo.join();
        }
    }
}
