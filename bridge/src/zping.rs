//! The same ping-pong as [`crate::ping`] over Zenoh (feature `zenoh`, not built by default): two
//! Zenoh peers with explicit endpoints (no scouting), an express publisher each way, state-sized
//! payloads, one per 300 µs. It measures what a Zenoh link would add to the loop's round trip.

use crate::cli::{ZPingArgs, ZPongArgs};
use anyhow::{Result, anyhow};
use deltaloop_transport::rt;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;
use zenoh::Wait;

fn session(key: &str, endpoint: &str) -> Result<zenoh::Session> {
    let mut c = zenoh::Config::default();
    let set = |c: &mut zenoh::Config, k: &str, v: &str| {
        c.insert_json5(k, v)
            .map_err(|e| anyhow!("zenoh config {k} = {v}: {e}"))
    };
    set(&mut c, "mode", "\"peer\"")?;
    set(&mut c, "scouting/multicast/enabled", "false")?;
    set(&mut c, key, &format!("[\"{endpoint}\"]"))?;
    zenoh::open(c)
        .wait()
        .map_err(|e| anyhow!("zenoh open: {e}"))
}

/// Times `count` round trips and prints the percentiles.
pub fn zping(a: &ZPingArgs) -> Result<()> {
    let s = session("connect/endpoints", &a.connect)?;
    let publisher = s
        .declare_publisher("deltaloop/bench/ping")
        .express(true)
        .wait()
        .map_err(|e| anyhow!("{e}"))?;
    let sub = s
        .declare_subscriber("deltaloop/bench/pong")
        .wait()
        .map_err(|e| anyhow!("{e}"))?;
    std::thread::sleep(Duration::from_millis(500));
    let mut payload = [0u8; 184];
    let mut rtt = Vec::with_capacity(a.count as usize);
    let mut lost = 0u64;
    for i in 0..(a.count as u64 + 1000) {
        let next = rt::now_ns() + a.period_us * 1000;
        payload[..8].copy_from_slice(&i.to_ne_bytes());
        let t = rt::now_ns();
        publisher
            .put(&payload[..])
            .wait()
            .map_err(|e| anyhow!("{e}"))?;
        let got = loop {
            match sub.recv_timeout(Duration::from_millis(100)) {
                Ok(Some(sample)) => {
                    let b = sample.payload().to_bytes();
                    if b.len() >= 8 && b[..8] == i.to_ne_bytes() {
                        break Some(rt::now_ns() - t);
                    }
                }
                _ => break None,
            }
        };
        match got {
            Some(d) if i >= 1000 => rtt.push(d),
            None => lost += 1,
            _ => {}
        }
        rt::sleep_until_ns(next);
    }
    crate::ping::print(&format!("zenoh ping-pong {}", a.connect), &mut rtt, lost);
    Ok(())
}

/// Echoes every ping until SIGTERM / SIGINT.
pub fn zpong(a: &ZPongArgs, term: &AtomicBool) -> Result<()> {
    let s = session("listen/endpoints", &a.listen)?;
    let publisher = s
        .declare_publisher("deltaloop/bench/pong")
        .express(true)
        .wait()
        .map_err(|e| anyhow!("{e}"))?;
    let sub = s
        .declare_subscriber("deltaloop/bench/ping")
        .wait()
        .map_err(|e| anyhow!("{e}"))?;
    while !term.load(Ordering::Relaxed) {
        if let Ok(Some(sample)) = sub.recv_timeout(Duration::from_millis(100)) {
            publisher
                .put(sample.payload().to_bytes().into_owned())
                .wait()
                .map_err(|e| anyhow!("{e}"))?;
        }
    }
    Ok(())
}
