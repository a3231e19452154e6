//! The two sockets of a bridge: the loop's UDP socket (one datagram per state or torque, with the
//! optional emulated delay, jitter and loss applied where it is sent) and the control plane's TCP
//! stream (frames: a u32 length, then a header and payload), both non-blocking, waited on with
//! `ppoll` together with the iceoryx2 wake-up event.

use crate::frame::{self, HEADER, Kind, MAX_DATAGRAM, MAX_FRAME};
use anyhow::{Context, Result, bail};
use std::io::{ErrorKind, Read, Write};
use std::net::{TcpStream, UdpSocket};
use std::os::fd::AsRawFd;

/// Emulated network on the sending side of each direction (this kernel has no `netem`): every
/// datagram is delayed by `delay_ns` plus a uniform draw from [0, `jitter_ns`], or lost with
/// probability `loss_ppm`/10⁶, from a seeded generator, so a run's link is reproducible. Order is
/// kept (a datagram never overtakes an earlier one), as on one wire.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Emulation {
    /// One-way delay, ns.
    pub delay_ns: u64,
    /// One-way jitter, ns: uniform in [0, jitter_ns] on top of the delay.
    pub jitter_ns: u64,
    /// Loss, parts per million of datagrams.
    pub loss_ppm: u32,
    /// Seed of the draws (the far side uses seed + 1 for its direction).
    pub seed: u64,
}

impl Emulation {
    pub fn is_off(&self) -> bool {
        self.delay_ns == 0 && self.jitter_ns == 0 && self.loss_ppm == 0
    }
}

/// SplitMix64: small, seeded, allocation-free.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }
}

/// Datagrams held back by the emulated delay at most; more are dropped (and counted).
const QUEUE: usize = 1024;

/// The loop's datagram socket, connected to the peer (the kernel drops datagrams from anyone
/// else), with its pre-allocated buffers.
pub struct Udp {
    pub sock: UdpSocket,
    key: u64,
    buf: [u8; MAX_DATAGRAM],
    emu: Emulation,
    rng: Rng,
    /// Ring of held datagrams: (due, length, bytes).
    queue: Box<[(u64, usize, [u8; MAX_DATAGRAM])]>,
    head: usize,
    len: usize,
    last_due: u64,
    /// Datagrams refused on receipt (another run, malformed), and the last reason.
    pub refused: u64,
    pub last_refusal: Option<String>,
    /// Datagrams the emulation dropped.
    pub emulated_lost: u64,
}

impl Udp {
    pub fn new(sock: UdpSocket, key: u64, emu: Emulation) -> Result<Self> {
        sock.set_nonblocking(true)?;
        Ok(Self {
            sock,
            key,
            buf: [0; MAX_DATAGRAM],
            emu,
            rng: Rng(emu.seed),
            queue: vec![(0, 0, [0u8; MAX_DATAGRAM]); if emu.is_off() { 0 } else { QUEUE }]
                .into_boxed_slice(),
            head: 0,
            len: 0,
            last_due: 0,
            refused: 0,
            last_refusal: None,
            emulated_lost: 0,
        })
    }

    /// Sends `kind` with `parts` as payload (now, or when the emulated delay says).
    pub fn send(&mut self, kind: Kind, parts: &[&[u8]], now_ns: u64) -> Result<()> {
        let mut n = HEADER;
        frame::put_header(&mut self.buf, kind, self.key);
        for p in parts {
            self.buf[n..n + p.len()].copy_from_slice(p);
            n += p.len();
        }
        if self.emu.is_off() {
            return self.send_raw(n);
        }
        if self.emu.loss_ppm > 0 && self.rng.next() % 1_000_000 < u64::from(self.emu.loss_ppm) {
            self.emulated_lost += 1;
            return Ok(());
        }
        let jitter = match self.emu.jitter_ns {
            0 => 0,
            j => self.rng.next() % (j + 1),
        };
        if self.len == self.queue.len() {
            self.emulated_lost += 1;
            return Ok(());
        }
        let due = (now_ns + self.emu.delay_ns + jitter).max(self.last_due);
        self.last_due = due;
        let slot = (self.head + self.len) % self.queue.len();
        self.queue[slot].0 = due;
        self.queue[slot].1 = n;
        self.queue[slot].2[..n].copy_from_slice(&self.buf[..n]);
        self.len += 1;
        self.flush(now_ns)
    }

    fn send_raw(&self, n: usize) -> Result<()> {
        self.send_bytes(&self.buf[..n])
    }

    fn send_bytes(&self, b: &[u8]) -> Result<()> {
        match self.sock.send(b) {
            Ok(_) => Ok(()),
            // The link is down or the peer's port closed: a lost datagram, as on a wire; the
            // loop's own rules (misses, silence) decide what that means.
            Err(e)
                if matches!(
                    e.kind(),
                    ErrorKind::WouldBlock
                        | ErrorKind::ConnectionRefused
                        | ErrorKind::HostUnreachable
                        | ErrorKind::NetworkUnreachable
                        | ErrorKind::NetworkDown
                ) || e.raw_os_error() == Some(libc::EHOSTUNREACH) =>
            {
                Ok(())
            }
            Err(e) => Err(e).context("send on the link's UDP socket"),
        }
    }

    /// Sends the held datagrams that are due.
    pub fn flush(&mut self, now_ns: u64) -> Result<()> {
        while self.len > 0 && self.queue[self.head].0 <= now_ns {
            let (_, n, b) = &self.queue[self.head];
            self.send_bytes(&b[..*n])?;
            self.head = (self.head + 1) % self.queue.len();
            self.len -= 1;
        }
        Ok(())
    }

    /// When the next held datagram is due, if any.
    pub fn next_due(&self) -> Option<u64> {
        (self.len > 0).then(|| self.queue[self.head].0)
    }

    /// Receives one datagram of this run: its kind and payload, None when there is none. Refused
    /// datagrams are counted and skipped.
    pub fn recv(&mut self) -> Result<Option<(Kind, &[u8])>> {
        loop {
            let n = match self.sock.recv(&mut self.buf) {
                Ok(n) => n,
                Err(e)
                    if matches!(
                        e.kind(),
                        ErrorKind::WouldBlock | ErrorKind::ConnectionRefused
                    ) =>
                {
                    return Ok(None);
                }
                Err(e) => return Err(e).context("receive on the link's UDP socket"),
            };
            match frame::parse(&self.buf[..n], Some(self.key)) {
                Ok(_) => {
                    // Parsed again to give the borrow its lifetime; cheap (a header).
                    let (k, p) = frame::parse(&self.buf[..n], Some(self.key))
                        .map_err(|e| anyhow::anyhow!("{e}"))?;
                    return Ok(Some((k, p)));
                }
                Err(e) => {
                    self.refused += 1;
                    if self.last_refusal.is_none() {
                        self.last_refusal = Some(e.to_string());
                    }
                }
            }
        }
    }
}

/// The control plane: a TCP stream with an input buffer for whole frames and an output buffer
/// written as the socket takes it (never blocking the loop).
pub struct Tcp {
    pub stream: TcpStream,
    key: Option<u64>,
    inbuf: Vec<u8>,
    in_len: usize,
    out: Vec<u8>,
    out_pos: usize,
    /// The peer closed the stream (or it failed).
    pub closed: bool,
}

impl Tcp {
    pub fn new(stream: TcpStream) -> Result<Self> {
        stream.set_nodelay(true)?;
        stream.set_nonblocking(true)?;
        Ok(Self {
            stream,
            key: None,
            inbuf: vec![0; 4 + MAX_FRAME],
            in_len: 0,
            out: Vec::with_capacity(4 * (HEADER + MAX_FRAME)),
            out_pos: 0,
            closed: false,
        })
    }

    /// From now on frames of other runs are refused.
    pub fn set_key(&mut self, key: u64) {
        self.key = Some(key);
    }

    /// Bytes queued and not yet written.
    pub fn pending(&self) -> usize {
        self.out.len() - self.out_pos
    }

    /// Queues a frame of `kind` (run `key`) and writes what the socket takes now.
    pub fn send(&mut self, kind: Kind, key: u64, parts: &[&[u8]]) -> Result<()> {
        self.queue(kind, key, parts)?;
        self.flush()
    }

    /// Queues a frame of `kind` (run `key`), written by the next [`Tcp::flush`] or send. What
    /// is already written is dropped from the front first when the frame would not fit the
    /// buffer otherwise, so a steady stream (a remote plant's telemetry) stays in the
    /// pre-allocated buffer. A frame that still does not fit is an error: the peer has taken
    /// nothing for seconds (regression: the buffer grew without bound, on the tick path). After
    /// the stream closed, frames are dropped: there is no one to take them.
    pub fn queue(&mut self, kind: Kind, key: u64, parts: &[&[u8]]) -> Result<()> {
        if self.closed {
            return Ok(());
        }
        let len: usize = HEADER + parts.iter().map(|p| p.len()).sum::<usize>();
        if self.out_pos == self.out.len() {
            self.out.clear();
            self.out_pos = 0;
        } else if self.out_pos > 0 && self.out.len() + 4 + len > self.out.capacity() {
            self.out.copy_within(self.out_pos.., 0);
            self.out.truncate(self.out.len() - self.out_pos);
            self.out_pos = 0;
        }
        if self.out.len() + 4 + len > self.out.capacity() {
            bail!(
                "the link's control connection is backed up: {} bytes not taken by the peer (the link is too slow or down)",
                self.pending()
            );
        }
        self.out.extend_from_slice(&(len as u32).to_ne_bytes());
        let at = self.out.len();
        self.out.resize(at + HEADER, 0);
        frame::put_header(&mut self.out[at..], kind, key);
        for p in parts {
            self.out.extend_from_slice(p);
        }
        Ok(())
    }

    /// Writes what the socket takes now.
    pub fn flush(&mut self) -> Result<()> {
        while self.out_pos < self.out.len() {
            match self.stream.write(&self.out[self.out_pos..]) {
                Ok(0) => {
                    self.closed = true;
                    return Ok(());
                }
                Ok(n) => self.out_pos += n,
                Err(e) if e.kind() == ErrorKind::WouldBlock => return Ok(()),
                Err(e) if e.kind() == ErrorKind::Interrupted => {}
                Err(_) => {
                    self.closed = true;
                    return Ok(());
                }
            }
        }
        Ok(())
    }

    /// Reads what has arrived and hands every whole frame to `f` (kind, payload). A malformed
    /// frame ends the stream with an error naming it.
    pub fn poll(&mut self, mut f: impl FnMut(Kind, &[u8]) -> Result<()>) -> Result<()> {
        loop {
            match self.stream.read(&mut self.inbuf[self.in_len..]) {
                Ok(0) => {
                    self.closed = true;
                    break;
                }
                Ok(n) => self.in_len += n,
                Err(e) if e.kind() == ErrorKind::WouldBlock => break,
                Err(e) if e.kind() == ErrorKind::Interrupted => {}
                Err(_) => {
                    self.closed = true;
                    break;
                }
            }
            if self.in_len == self.inbuf.len() {
                break;
            }
        }
        let mut at = 0;
        while self.in_len - at >= 4 {
            let mut l = [0u8; 4];
            l.copy_from_slice(&self.inbuf[at..at + 4]);
            let len = u32::from_ne_bytes(l) as usize;
            if !(HEADER..=MAX_FRAME).contains(&len) {
                bail!("control frame of {len} bytes (allowed {HEADER}..={MAX_FRAME})");
            }
            if self.in_len - at - 4 < len {
                break;
            }
            let b = &self.inbuf[at + 4..at + 4 + len];
            let (kind, payload) =
                frame::parse(b, self.key).map_err(|e| anyhow::anyhow!("control frame: {e}"))?;
            f(kind, payload)?;
            at += 4 + len;
        }
        self.inbuf.copy_within(at..self.in_len, 0);
        self.in_len -= at;
        Ok(())
    }
}

/// Waits until one of `fds` is readable (or writable, for those that ask) or `timeout_ns` passes;
/// an interrupted wait returns early. The caller looks at everything afterwards.
pub fn wait(fds: &mut [libc::pollfd], timeout_ns: u64) -> Result<()> {
    let ts = libc::timespec {
        tv_sec: (timeout_ns / 1_000_000_000) as libc::time_t,
        tv_nsec: (timeout_ns % 1_000_000_000) as libc::c_long,
    };
    // SAFETY: fds is a valid slice of pollfd we own, ts a valid timespec, no signal mask change.
    let r = unsafe {
        libc::ppoll(
            fds.as_mut_ptr(),
            fds.len() as libc::nfds_t,
            &ts,
            std::ptr::null(),
        )
    };
    if r < 0 {
        let e = std::io::Error::last_os_error();
        if e.kind() != ErrorKind::Interrupted {
            return Err(e).context("ppoll");
        }
    }
    Ok(())
}

/// A pollfd for a wake-up event's listener (readable when an event is pending).
pub fn event(
    listener: &iceoryx2::port::listener::Listener<deltaloop_transport::ipc::Svc>,
) -> libc::pollfd {
    use iceoryx2::prelude::FileDescriptorBased;
    // SAFETY: the descriptor belongs to `listener`, which outlives the poll; we only poll it.
    let fd = unsafe { listener.file_descriptor().native_handle() };
    libc::pollfd {
        fd,
        events: libc::POLLIN,
        revents: 0,
    }
}

/// The wait's timeout: 1 ms (the control plane's pace), or less when an emulated datagram is
/// due; 0 (poll) when it is due within [`EMULATION_SPIN_NS`], since a timed wake-up on a VM comes
/// tens of µs late and would add that to every emulated delay.
pub fn timeout_ns(udp: &Udp, now_ns: u64) -> u64 {
    match udp.next_due().map(|d| d.saturating_sub(now_ns)) {
        Some(left) if left <= EMULATION_SPIN_NS => 0,
        Some(left) => (left - EMULATION_SPIN_NS).min(1_000_000),
        None => 1_000_000,
    }
}

/// How close to an emulated datagram's due time the bridge stops sleeping and polls, ns.
pub const EMULATION_SPIN_NS: u64 = 100_000;

/// A pollfd for reading `fd`.
pub fn readable(fd: &impl AsRawFd) -> libc::pollfd {
    libc::pollfd {
        fd: fd.as_raw_fd(),
        events: libc::POLLIN,
        revents: 0,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pair(emu: Emulation) -> (Udp, Udp) {
        let a = UdpSocket::bind("127.0.0.1:0").unwrap();
        let b = UdpSocket::bind("127.0.0.1:0").unwrap();
        a.connect(b.local_addr().unwrap()).unwrap();
        b.connect(a.local_addr().unwrap()).unwrap();
        (
            Udp::new(a, 3, emu).unwrap(),
            Udp::new(b, 3, Emulation::default()).unwrap(),
        )
    }

    #[test]
    fn emulated_loss_is_seeded_and_near_its_rate() {
        let emu = Emulation {
            loss_ppm: 100_000,
            seed: 42,
            ..Default::default()
        };
        let lost = |seed| {
            let (mut a, _b) = pair(Emulation { seed, ..emu });
            for i in 0..10_000u64 {
                a.send(Kind::Ping, &[&i.to_ne_bytes(), &[0u8; 160]], 0)
                    .unwrap();
            }
            a.emulated_lost
        };
        assert_eq!(lost(42), lost(42));
        assert!((800..1200).contains(&lost(42)), "{}", lost(42));
        assert_ne!(lost(42), lost(43));
    }

    #[test]
    fn emulated_delay_holds_a_datagram_until_due_and_keeps_order() {
        let (mut a, mut b) = pair(Emulation {
            delay_ns: 1_000,
            jitter_ns: 500,
            seed: 1,
            ..Default::default()
        });
        for i in 0..5u64 {
            a.send(Kind::Ping, &[&i.to_ne_bytes(), &[0u8; 160]], 10)
                .unwrap();
        }
        std::thread::sleep(std::time::Duration::from_millis(20));
        assert!(b.recv().unwrap().is_none());
        let due = a.next_due().unwrap();
        assert!((1_010..=1_510).contains(&due), "{due}");
        a.flush(10_000).unwrap();
        std::thread::sleep(std::time::Duration::from_millis(20));
        for i in 0..5u64 {
            let (k, p) = b.recv().unwrap().unwrap();
            assert_eq!((k, frame::read::<u64>(&p[..8])), (Kind::Ping, Some(i)));
        }
    }
}
