//! `deltaloop bench ros2`: what ROS 2's transport costs a 3.3 kHz loop, against the loop's own:
//! paced ping-pongs of state-sized messages over iceoryx2, UDP on loopback and DDS, the rows
//! interleaved round by round so that a drift of the machine hits all three.

use anyhow::Result;
use deltaloop_baseline::paced::{self, PingPong};

/// Ts at 3.3 kHz, ns.
const PERIOD_NS: u64 = 300_000;

/// The rows in order.
const ROWS: [&str; 3] = [
    "iceoryx2 (shared memory, blocking on its event)",
    "UDP on loopback (blocking recv)",
    "DDS (RustDDS, reliable, loopback)",
];

/// `count` round trips of DDS on `domain`, one every [`PERIOD_NS`].
#[cfg(feature = "ros2")]
fn dds(domain: u16, count: u64) -> Result<PingPong> {
    let mut dds = deltaloop_ros2::bench::Dds::open(domain)?;
    paced::paced(count, PERIOD_NS, |seq| dds.round(seq, paced::PONG_TIMEOUT))
}

#[cfg(not(feature = "ros2"))]
fn dds(_domain: u16, _count: u64) -> Result<PingPong> {
    anyhow::bail!("bench ros2: this deltaloop was built without its `ros2` feature")
}

/// Runs the rounds and prints the table and its `key=value` line.
pub fn run(count: u64, rounds: u32, domain: u16) -> Result<()> {
    println!(
        "deltaloop bench ros2: {rounds} round(s) of {count} round trips per row, one every {} µs (3.3 kHz), rows interleaved",
        PERIOD_NS / 1000
    );
    let mut rows: Vec<Option<PingPong>> = vec![None, None, None];
    for round in 0..rounds {
        let got = [
            paced::iox(count, PERIOD_NS)?,
            paced::udp(count, PERIOD_NS)?,
            dds(domain, count)?,
        ];
        for (acc, g) in rows.iter_mut().zip(got) {
            match acc {
                None => *acc = Some(g),
                Some(a) => {
                    a.rtt.add(&g.rtt)?;
                    a.lost += g.lost;
                    a.count += g.count;
                }
            }
        }
        eprintln!("round {} of {rounds} done", round + 1);
    }
    let rows: Vec<PingPong> = rows.into_iter().flatten().collect();
    println!("| transport | round trip p50 / p99 / p99.9 (µs) | lost |");
    println!("|---|---|---|");
    for (name, r) in ROWS.iter().zip(&rows) {
        println!(
            "| {name} | {:.1} / {:.1} / {:.1} | {} of {} |",
            r.us(0.5),
            r.us(0.99),
            r.us(0.999),
            r.lost,
            r.count
        );
    }
    let (iox, udp, dds) = (&rows[0], &rows[1], &rows[2]);
    println!(
        "iox_p50_us={:.1} udp_p50_us={:.1} dds_p50_us={:.1} dds_p99_9_us={:.1} dds_over_iox={:.2} dds_over_udp={:.2} dds_lost={}",
        iox.us(0.5),
        udp.us(0.5),
        dds.us(0.5),
        dds.us(0.999),
        dds.us(0.5) / iox.us(0.5),
        dds.us(0.5) / udp.us(0.5),
        dds.lost
    );
    Ok(())
}
