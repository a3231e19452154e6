//! Criterion benches of the link's sealing: one state datagram (168-byte payload) and one torque
//! datagram (three replies, 432 bytes) sealed (ChaCha20-Poly1305 under the session's key,
//! header authenticated) and sealed + opened, against the same run's baseline of writing the
//! header and copying the payload unsealed. `cargo bench --bench link`.

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use deltaloop_bridge::frame::{self, HEADER, Kind, TAG};
use deltaloop_bridge::seal::{Channel, End, Session};
use std::hint::black_box;

fn link(c: &mut Criterion) {
    let session = Session::generate().expect("random");
    for (name, kind, len) in [
        ("state", Kind::State, 168usize),
        ("torque", Kind::Torque, 3 * 144),
    ] {
        let payload = vec![0x5au8; len];
        let mut buf = vec![0u8; HEADER + len + TAG];
        let mut g = c.benchmark_group(format!("link/{name}"));
        g.throughput(Throughput::Bytes(len as u64));
        g.bench_function("baseline: header + copy, unsealed", |b| {
            b.iter(|| {
                frame::put_header(&mut buf, kind, session.id, 0);
                buf[HEADER..HEADER + len].copy_from_slice(black_box(&payload));
                black_box(&buf);
            })
        });
        let mut tx = session.sealer(End::Far, Channel::Udp);
        g.bench_function("seal", |b| {
            b.iter(|| {
                frame::put_header(&mut buf, kind, session.id, tx.next_counter());
                buf[HEADER..HEADER + len].copy_from_slice(black_box(&payload));
                let (h, body) = buf.split_at_mut(HEADER);
                let tag = tx.seal(h, &mut body[..len]);
                buf[HEADER + len..].copy_from_slice(&tag);
                black_box(&buf);
            })
        });
        let mut tx = session.sealer(End::Far, Channel::Udp);
        let mut rx = session.opener(End::Near, Channel::Udp);
        g.bench_function("seal + open", |b| {
            b.iter(|| {
                let counter = tx.next_counter();
                frame::put_header(&mut buf, kind, session.id, counter);
                buf[HEADER..HEADER + len].copy_from_slice(black_box(&payload));
                let (h, rest) = buf.split_at_mut(HEADER);
                let tag = tx.seal(h, &mut rest[..len]);
                rest[len..].copy_from_slice(&tag);
                rx.open(h, counter, rest).expect("opens");
                black_box(&buf);
            })
        });
        g.finish();
    }
}

criterion_group! {
    name = benches;
    // No plots: this machine has no fonts for criterion's plotters backend.
    config = Criterion::default().without_plots();
    targets = link
}
criterion_main!(benches);
