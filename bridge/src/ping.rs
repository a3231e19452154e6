//! The baseline: a plain UDP ping-pong of state-sized datagrams between the same two hosts,
//! nothing else on the path (no iceoryx2, no bridge). `ping` prints p50/p99/p99.9/max of the
//! round trip, µs.

use crate::bytes;
use crate::cli::{PingArgs, PongArgs};
use crate::frame::{self, Kind};
use crate::link::{self, Udp};
use anyhow::{Context, Result};
use deltaloop_transport::rt;
use std::net::{SocketAddr, UdpSocket};
use std::sync::atomic::{AtomicBool, Ordering};

const KEY: u64 = 0x7069_6e67;

/// Sends `count` pings, one per period, each waited for with `ppoll`, and prints the percentiles.
pub fn ping(a: &PingArgs) -> Result<()> {
    let s = UdpSocket::bind(SocketAddr::new(
        if a.connect.is_ipv4() {
            [0, 0, 0, 0].into()
        } else {
            std::net::Ipv6Addr::UNSPECIFIED.into()
        },
        0,
    ))?;
    s.connect(a.connect).context("connect to the echo side")?;
    let mut u = Udp::plain(s, KEY)?;
    let mut rtt = Vec::with_capacity(a.count as usize);
    let mut lost = 0u64;
    for i in 0..(a.count as u64 + 1000) {
        let next = rt::now_ns() + a.period_us * 1000;
        let t = rt::now_ns();
        u.send(Kind::Ping, &[&i.to_ne_bytes(), &[0u8; 160]], t)?;
        let deadline = t + 100_000_000;
        let got = loop {
            let mut fds = [link::readable(&u.sock)];
            link::wait(&mut fds, deadline.saturating_sub(rt::now_ns()))?;
            let now = rt::now_ns();
            match u.recv()? {
                Some((Kind::Pong, p)) if bytes::read::<u64>(&p[..8]) == Some(i) => {
                    break Some(now - t);
                }
                Some(_) => {}
                None if now >= deadline => break None,
                None => {}
            }
        };
        match got {
            Some(d) if i >= 1000 => rtt.push(d),
            None => lost += 1,
            _ => {}
        }
        rt::sleep_until_ns(next);
    }
    print(&format!("udp ping-pong {}", a.connect), &mut rtt, lost);
    Ok(())
}

/// Prints the percentiles of `rtt` (ns) in µs, one line.
pub fn print(what: &str, rtt: &mut [u64], lost: u64) {
    rtt.sort_unstable();
    let p = |q: f64| {
        rtt.get(((rtt.len() as f64 * q) as usize).min(rtt.len().saturating_sub(1)))
            .map_or(0.0, |v| *v as f64 / 1e3)
    };
    println!(
        "{what}: {} round trips, p50 {:.1} µs, p99 {:.1} µs, p99.9 {:.1} µs, max {:.1} µs, lost {lost}",
        rtt.len(),
        p(0.5),
        p(0.99),
        p(0.999),
        p(1.0)
    );
}

/// Echoes every ping until SIGTERM / SIGINT.
pub fn pong(a: &PongArgs, term: &AtomicBool) -> Result<()> {
    let s = UdpSocket::bind(a.listen).with_context(|| format!("bind {}", a.listen))?;
    let mut peer = None;
    let mut buf = [0u8; 512];
    s.set_read_timeout(Some(std::time::Duration::from_millis(100)))?;
    while !term.load(Ordering::Relaxed) {
        let Ok((n, from)) = s.recv_from(&mut buf) else {
            continue;
        };
        if let Ok((Kind::Ping, _)) = frame::parse(&buf[..n], Some(KEY)) {
            if peer != Some(from) {
                peer = Some(from);
            }
            buf[4..6].copy_from_slice(&(Kind::Pong as u16).to_ne_bytes());
            let _ = s.send_to(&buf[..n], from);
        }
    }
    Ok(())
}
