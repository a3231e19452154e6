//! The DDS ping-pong of `bench ros2`: two participants of this process on loopback, a
//! JointState each way per period (reliable, the QoS of the loop's topics), the reader woken by
//! RustDDS's notification (mio), as `--controller ros2` waits.

use crate::msg::{self, JointState, Time};
use crate::node::{Participant, Settings, Waiting, reliable, wait_matched};
use anyhow::{Context, Result, bail};
use deltaloop_baseline::paced::{PONG_TIMEOUT, PingPong, paced};
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

/// `count` round trips every `period_ns` over DDS on `domain`, this host only.
pub fn dds(domain: u16, count: u64, period_ns: u64) -> Result<PingPong> {
    let (ready_tx, ready_rx) = std::sync::mpsc::channel::<()>();
    let echo = std::thread::spawn(move || -> Result<()> {
        let p = Participant::join(Settings::localhost(domain))?;
        let w = p.writer::<JointState>("deltaloop_bench_pong", PONG, reliable(10))?;
        let mut r =
            Waiting::new(p.reader::<JointState>("deltaloop_bench_pong", PING, reliable(10))?)?;
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
    let mut r = Waiting::new(r)?;
    let state = |seq: u64| msg::joint_state(seq, &[0.1; 3], &[0.2; 3], &[0.3; 3]);
    let out = paced(count, period_ns, |seq| {
        w.write(state(seq), None)
            .map_err(|e| anyhow::anyhow!("DDS write: {e:?}"))?;
        let until = Instant::now() + PONG_TIMEOUT;
        let mut back = false;
        while !back
            && take(&mut r, until, |m| {
                back |= m.header.stamp == Time::of_ns(seq)
            })
        {}
        Ok(back)
    });
    drop(w);
    let _ = echo.join();
    out
}
