//! The loop's datagram socket of a run's link: one sealed datagram per state or reply, with the
//! optional emulated delay, jitter and loss applied where it is sent.

use crate::frame::{self, HEADER, Kind, MAX_DATAGRAM, TAG};
use crate::seal::{Channel, End, Opener, Refusals, Sealer, Session};
use anyhow::{Context, Result};
use std::io::ErrorKind;
use std::net::UdpSocket;
use std::os::fd::AsRawFd;

pub use crate::emulation::Emulation;

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

/// Datagrams taken per `recvmmsg`: a drain that finds one (the loop's usual case) learns in the
/// same system call that there is no second, instead of asking again.
const BATCH: usize = 8;

/// A received datagram: its kind, its payload, and when it reached the socket (CLOCK_MONOTONIC
/// ns; None if the kernel did not say).
pub type Stamped<'a> = (Kind, &'a [u8], Option<u64>);

/// Received datagrams not yet handed out.
struct Inbox {
    bufs: Box<[[u8; MAX_DATAGRAM]; BATCH]>,
    lens: [usize; BATCH],
    /// When the kernel took each datagram in (SO_TIMESTAMPNS, moved to CLOCK_MONOTONIC ns; 0:
    /// not told).
    stamps: [u64; BATCH],
    /// Room for each datagram's control message (its timestamp).
    cmsgs: [[u64; 8]; BATCH],
    /// How many `bufs` hold datagrams, and the next to hand out.
    n: usize,
    next: usize,
    /// The last `recvmmsg` found fewer than it could take: once its datagrams are handed out,
    /// the drain ends without another system call.
    short: bool,
}

/// The refusal of a datagram the kernel cut to the buffer (the link's largest is
/// [`MAX_DATAGRAM`], 496 bytes).
const OVERSIZED: &str = "a datagram longer than the largest of the link (496 bytes)";
const _: () = assert!(MAX_DATAGRAM == 496, "OVERSIZED names the size");

/// What a loop process's socket counted on the direct path, for its bridge's report.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct ProcessCounts {
    /// Datagrams refused, by reason ([`crate::seal::Refusals`]).
    pub refused: [u64; 4],
    /// Datagrams the emulation dropped.
    pub emulated_lost: u64,
    /// ICMP-reported errors on the socket ([`Udp::icmp_errors`]).
    pub icmp_errors: u64,
    /// The first refusal's reason, in words, for the bridge's warning.
    pub first_refusal: Option<String>,
}

/// The loop's datagram socket, connected to the peer (the kernel drops datagrams from anyone
/// else), with its pre-allocated buffers and, on a run's link, the session's sealing.
pub struct Udp {
    pub sock: UdpSocket,
    session: u64,
    /// Sealing and opening (None: the bench's plain ping-pong, never a run).
    seal: Option<(Sealer, Opener)>,
    buf: [u8; MAX_DATAGRAM],
    inbox: Inbox,
    emu: Emulation,
    rng: Rng,
    /// Ring of held datagrams: (due, length, bytes).
    queue: Box<[(u64, usize, [u8; MAX_DATAGRAM])]>,
    head: usize,
    len: usize,
    last_due: u64,
    /// Datagrams refused on receipt, by reason, and the first reason in words.
    pub refused: Refusals,
    /// The first refusal's reason, in words (built once, on the first refusal; a constant one
    /// costs no allocation).
    pub last_refusal: Option<std::borrow::Cow<'static, str>>,
    /// Datagrams the emulation dropped.
    pub emulated_lost: u64,
    /// Errors the kernel reported on this socket from an ICMP message quoting its addresses
    /// (port, host or network unreachable: [`reported`]): each fails the next send or receive
    /// once, and that datagram is sent (or read) again. The peer's host says so when its port
    /// is closed; anyone who knows the link's addresses can too, without the key.
    pub icmp_errors: u64,
}

impl Udp {
    /// The loop's socket of a run's link: every datagram sealed under `session` as end `me`.
    pub fn sealed(sock: UdpSocket, session: &Session, me: End, emu: Emulation) -> Result<Self> {
        let seal = (
            session.sealer(me, Channel::Udp),
            session.opener(me, Channel::Udp),
        );
        Self::new(sock, session.id, Some(seal), emu)
    }

    /// A socket handed on by a bridge: its sealing goes on from the bridge's counters.
    pub fn resumed(
        sock: UdpSocket,
        session: u64,
        (seal, open): (Sealer, Opener),
        emu: Emulation,
    ) -> Result<Self> {
        Self::new(sock, session, Some((seal, open)), emu)
    }

    /// The counter of the next datagram sealed, and the highest opened.
    pub fn counters(&self) -> (u64, Option<u64>) {
        self.seal
            .as_ref()
            .map_or((0, None), |(s, o)| (s.next_counter(), o.top()))
    }

    /// The emulation this socket applies.
    pub fn emulation(&self) -> Emulation {
        self.emu
    }

    /// A socket whose datagrams carry `key` in the clear (the bench's ping-pong, never a run).
    pub fn plain(sock: UdpSocket, key: u64) -> Result<Self> {
        Self::new(sock, key, None, Emulation::default())
    }

    fn new(
        sock: UdpSocket,
        session: u64,
        seal: Option<(Sealer, Opener)>,
        emu: Emulation,
    ) -> Result<Self> {
        sock.set_nonblocking(true)?;
        // The kernel stamps each datagram as it arrives: a receiver that was itself preempted
        // still learns when the datagram came, not when it looked.
        let on: libc::c_int = 1;
        // SAFETY: a valid socket and a c_int option value of the size given.
        let r = unsafe {
            libc::setsockopt(
                sock.as_raw_fd(),
                libc::SOL_SOCKET,
                libc::SO_TIMESTAMPNS,
                (&on as *const libc::c_int).cast(),
                std::mem::size_of::<libc::c_int>() as libc::socklen_t,
            )
        };
        if r != 0 {
            return Err(std::io::Error::last_os_error())
                .context("SO_TIMESTAMPNS on the link's socket");
        }
        Ok(Self {
            sock,
            session,
            seal,
            buf: [0; MAX_DATAGRAM],
            inbox: Inbox {
                bufs: Box::new([[0; MAX_DATAGRAM]; BATCH]),
                lens: [0; BATCH],
                stamps: [0; BATCH],
                cmsgs: [[0; 8]; BATCH],
                n: 0,
                next: 0,
                short: false,
            },
            emu,
            rng: Rng(emu.seed),
            queue: vec![(0, 0, [0u8; MAX_DATAGRAM]); if emu.is_off() { 0 } else { QUEUE }]
                .into_boxed_slice(),
            head: 0,
            len: 0,
            last_due: 0,
            refused: Refusals::default(),
            last_refusal: None,
            emulated_lost: 0,
            icmp_errors: 0,
        })
    }

    /// Sends `kind` with `parts` as payload (now, or when the emulated delay says), sealed.
    pub fn send(&mut self, kind: Kind, parts: &[&[u8]], now_ns: u64) -> Result<()> {
        let counter = self.seal.as_ref().map_or(0, |s| s.0.next_counter());
        frame::put_header(&mut self.buf, kind, self.session, counter);
        let mut n = HEADER;
        for p in parts {
            self.buf[n..n + p.len()].copy_from_slice(p);
            n += p.len();
        }
        if let Some((sealer, _)) = &mut self.seal {
            let (head, body) = self.buf.split_at_mut(HEADER);
            let tag = sealer.seal(head, &mut body[..n - HEADER]);
            self.buf[n..n + TAG].copy_from_slice(&tag);
            n += TAG;
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
            j => self.rng.next() % j.saturating_add(1),
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

    fn send_raw(&mut self, n: usize) -> Result<()> {
        send_bytes(&self.sock, &self.buf[..n], &mut self.icmp_errors)
    }

    /// Sends the held datagrams that are due.
    pub fn flush(&mut self, now_ns: u64) -> Result<()> {
        while self.len > 0 && self.queue[self.head].0 <= now_ns {
            let (_, n, b) = &self.queue[self.head];
            send_bytes(&self.sock, &b[..*n], &mut self.icmp_errors)?;
            self.head = (self.head + 1) % self.queue.len();
            self.len -= 1;
        }
        Ok(())
    }

    /// Adds what a loop process's socket counted ([`ProcessCounts`], the direct
    /// path) to this socket's counts; its first refusal's reason stands if this one has none.
    pub fn absorb(&mut self, c: ProcessCounts) {
        for (a, b) in self.refused.counts.iter_mut().zip(c.refused) {
            *a = a.saturating_add(b);
        }
        self.emulated_lost = self.emulated_lost.saturating_add(c.emulated_lost);
        self.icmp_errors = self.icmp_errors.saturating_add(c.icmp_errors);
        if self.last_refusal.is_none() {
            self.last_refusal = c.first_refusal.map(std::borrow::Cow::Owned);
        }
    }

    /// When the next held datagram is due, if any.
    pub fn next_due(&self) -> Option<u64> {
        (self.len > 0).then(|| self.queue[self.head].0)
    }

    /// Receives one datagram of this run: its kind and payload (opened), None when there is
    /// none. Refused datagrams (malformed, of another run, forged, replayed) are counted by
    /// reason and skipped: never applied.
    ///
    /// A drain (`while let Some(..) = recv()`) costs one system call per [`BATCH`] datagrams: the
    /// call that finds fewer than a batch also tells that the socket is empty.
    pub fn recv(&mut self) -> Result<Option<(Kind, &[u8])>> {
        Ok(self.recv_stamped()?.map(|(k, p, _)| (k, p)))
    }

    /// [`Udp::recv`], with when the datagram reached this host's socket (the kernel's stamp,
    /// CLOCK_MONOTONIC ns; None if the kernel gave none).
    pub fn recv_stamped(&mut self) -> Result<Option<Stamped<'_>>> {
        loop {
            let ib = &mut self.inbox;
            if ib.next == ib.n {
                if std::mem::take(&mut ib.short) {
                    return Ok(None);
                }
                let got = fill(&self.sock, ib, &mut self.icmp_errors)
                    .context("receive on the link's UDP socket")?;
                if got == 0 {
                    return Ok(None);
                }
                ib.short = got < BATCH;
            }
            let i = ib.next;
            ib.next += 1;
            let len = ib.lens[i];
            let rx = ib.stamps[i];
            if len > MAX_DATAGRAM {
                // Cut by the kernel to the buffer: not a datagram of the link, whatever its
                // first bytes say.
                self.refused.add(crate::seal::Refusal::Malformed);
                if self.last_refusal.is_none() {
                    self.last_refusal = Some(OVERSIZED.into());
                }
                continue;
            }
            match open(
                &mut ib.bufs[i][..len],
                self.session,
                self.seal.as_mut().map(|s| &mut s.1),
            ) {
                Ok((kind, len)) => {
                    let at = (rx > 0).then_some(rx);
                    return Ok(Some((kind, &self.inbox.bufs[i][HEADER..HEADER + len], at)));
                }
                Err((reason, why)) => {
                    self.refused.add(reason);
                    if self.last_refusal.is_none() {
                        self.last_refusal = Some(why.into());
                    }
                }
            }
        }
    }
}

/// Tries of one send (or receive) at most while the kernel reports errors ([`send_bytes`]):
/// more in a row mean the path itself is down (no route), not an earlier datagram's report.
const SEND_TRIES: usize = 3;

/// Sends `b` on the connected socket `sock`. An error the network reported for an earlier
/// datagram ([`reported`]: the kernel hands it to the next call, which sends nothing) is
/// counted in `icmp_errors` and the datagram sent again: one more system call (regression: it
/// was taken for sent, and ICMP port-unreachable messages from anyone quoting the link's
/// addresses dropped 40 % of the plant's states with nothing on record). A full buffer, or an
/// error still there after [`SEND_TRIES`], is a lost datagram, as on a wire: the loop's own
/// rules (misses, silence) decide what that means.
pub fn send_bytes(sock: &UdpSocket, b: &[u8], icmp_errors: &mut u64) -> Result<()> {
    for _ in 0..SEND_TRIES {
        match sock.send(b) {
            Ok(_) => return Ok(()),
            Err(e) if reported(&e) => *icmp_errors = icmp_errors.saturating_add(1),
            Err(e) if e.kind() == ErrorKind::WouldBlock => return Ok(()),
            Err(e) => return Err(e).context("send on the link's UDP socket"),
        }
    }
    Ok(())
}

/// Whether `e` is an error the kernel keeps on a connected UDP socket from an ICMP message
/// quoting its addresses (port, protocol, host or network unreachable, a parameter problem),
/// and hands to the next send or receive once; or the same from the local route.
fn reported(e: &std::io::Error) -> bool {
    matches!(
        e.raw_os_error(),
        Some(
            libc::ECONNREFUSED
                | libc::EHOSTUNREACH
                | libc::ENETUNREACH
                | libc::EHOSTDOWN
                | libc::ENETDOWN
                | libc::ENOPROTOOPT
                | libc::EPROTO
        )
    )
}

/// Opens message `b` (header, sealed payload, tag) of `session` in place with `opener` (None:
/// unsealed): its kind and the payload's length at `b[HEADER..]`, or the reason and a line.
pub fn open(
    b: &mut [u8],
    session: u64,
    opener: Option<&mut Opener>,
) -> std::result::Result<(Kind, usize), (crate::seal::Refusal, String)> {
    let refused = |e: frame::Refused| (e.reason(), e.to_string());
    let h = frame::head(b, Some(session)).map_err(refused)?;
    let mut len = b.len() - HEADER;
    if let Some(o) = opener {
        if len < TAG {
            return Err((
                crate::seal::Refusal::Malformed,
                format!("{} bytes, shorter than a sealed message", b.len()),
            ));
        }
        let (head, sealed) = b.split_at_mut(HEADER);
        len = o.open(head, h.counter, sealed).map_err(|r| {
            (
                r,
                format!("{:?} counter {}: {}", h.kind, h.counter, r.name()),
            )
        })?;
    }
    frame::check_size(h.kind, &b[HEADER..HEADER + len]).map_err(refused)?;
    Ok((h.kind, len))
}

/// Takes what the socket holds, up to a batch, into `ib` without blocking; how many (0:
/// nothing waiting). An error reported for an earlier send ([`reported`]) fails the call once
/// before the datagrams waiting: counted in `icmp_errors`, and the call made again. A datagram
/// the kernel cut to the buffer gets a length over [`MAX_DATAGRAM`] (`MSG_TRUNC`).
fn fill(sock: &UdpSocket, ib: &mut Inbox, icmp_errors: &mut u64) -> std::io::Result<usize> {
    for _ in 1..SEND_TRIES {
        match fill_once(sock, ib) {
            Err(e) if reported(&e) => *icmp_errors = icmp_errors.saturating_add(1),
            r => return r,
        }
    }
    match fill_once(sock, ib) {
        Err(e) if reported(&e) => {
            *icmp_errors = icmp_errors.saturating_add(1);
            Ok(0)
        }
        r => r,
    }
}

fn fill_once(sock: &UdpSocket, ib: &mut Inbox) -> std::io::Result<usize> {
    // SAFETY: each iovec points into its own buffer of `ib.bufs`, which outlives the call; the
    // headers are plain C structs that zero is a valid value of (no address, no control data).
    let mut iov: [libc::iovec; BATCH] = unsafe { std::mem::zeroed() };
    let mut msgs: [libc::mmsghdr; BATCH] = unsafe { std::mem::zeroed() };
    for (((v, m), b), c) in iov
        .iter_mut()
        .zip(&mut msgs)
        .zip(ib.bufs.iter_mut())
        .zip(ib.cmsgs.iter_mut())
    {
        v.iov_base = b.as_mut_ptr().cast();
        v.iov_len = MAX_DATAGRAM;
        m.msg_hdr.msg_iov = v;
        m.msg_hdr.msg_iovlen = 1;
        m.msg_hdr.msg_control = c.as_mut_ptr().cast();
        m.msg_hdr.msg_controllen = std::mem::size_of_val(c);
    }
    // SAFETY: `msgs` holds BATCH valid headers as set up above; no timeout.
    let r = unsafe {
        libc::recvmmsg(
            sock.as_raw_fd(),
            msgs.as_mut_ptr(),
            BATCH as libc::c_uint,
            libc::MSG_DONTWAIT,
            std::ptr::null_mut(),
        )
    };
    ib.next = 0;
    ib.n = 0;
    if r < 0 {
        let e = std::io::Error::last_os_error();
        return match e.kind() {
            ErrorKind::WouldBlock => Ok(0),
            _ => Err(e),
        };
    }
    ib.n = r as usize;
    let offset = ClockOffset::now();
    for ((len, stamp), m) in ib.lens.iter_mut().zip(&mut ib.stamps).zip(&msgs).take(ib.n) {
        // Cut to the buffer (longer than any datagram of the link): marked, refused as
        // malformed on reading (regression: it was read as a datagram of 496 bytes).
        *len = if m.msg_hdr.msg_flags & libc::MSG_TRUNC != 0 {
            MAX_DATAGRAM + 1
        } else {
            (m.msg_len as usize).min(MAX_DATAGRAM)
        };
        *stamp = offset.monotonic_of(kernel_stamp(&m.msg_hdr));
    }
    Ok(ib.n)
}

/// The SCM_TIMESTAMPNS of a received message, CLOCK_REALTIME ns; 0 if it has none.
fn kernel_stamp(h: &libc::msghdr) -> u64 {
    // SAFETY: `h` is a header the kernel filled, its control buffer ours and `msg_controllen`
    // long; the CMSG_* walk stays inside it, and the timestamp is read unaligned.
    unsafe {
        let mut c = libc::CMSG_FIRSTHDR(h);
        while !c.is_null() {
            if (*c).cmsg_level == libc::SOL_SOCKET && (*c).cmsg_type == libc::SCM_TIMESTAMPNS {
                let ts: libc::timespec = std::ptr::read_unaligned(libc::CMSG_DATA(c).cast());
                return ts.tv_sec as u64 * 1_000_000_000 + ts.tv_nsec as u64;
            }
            c = libc::CMSG_NXTHDR(h, c);
        }
    }
    0
}

/// CLOCK_REALTIME and CLOCK_MONOTONIC read together (two vDSO reads): what maps the kernel's
/// receive stamps of one batch onto the loop's clock.
struct ClockOffset {
    realtime_ns: u64,
    monotonic_ns: u64,
}

impl ClockOffset {
    fn now() -> Self {
        let read = |clock| {
            let mut ts = libc::timespec {
                tv_sec: 0,
                tv_nsec: 0,
            };
            // SAFETY: clock_gettime writes into the timespec we own; both clocks exist on Linux.
            unsafe { libc::clock_gettime(clock, &mut ts) };
            ts.tv_sec as u64 * 1_000_000_000 + ts.tv_nsec as u64
        };
        Self {
            realtime_ns: read(libc::CLOCK_REALTIME),
            monotonic_ns: read(libc::CLOCK_MONOTONIC),
        }
    }

    /// A CLOCK_REALTIME time (ns) as CLOCK_MONOTONIC; 0 stays 0, a stamp from the future (the
    /// realtime clock stepped back) is now.
    fn monotonic_of(&self, realtime_ns: u64) -> u64 {
        if realtime_ns == 0 {
            return 0;
        }
        self.monotonic_ns
            .saturating_sub(self.realtime_ns.saturating_sub(realtime_ns))
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
pub fn event(listener: &deltaloop_transport::ipc::Wake) -> libc::pollfd {
    libc::pollfd {
        fd: listener.fd(),
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
    use crate::bytes;
    use crate::seal::{End, Session};
    use std::net::UdpSocket;

    fn pair(emu: Emulation) -> (Udp, Udp) {
        let a = UdpSocket::bind("127.0.0.1:0").unwrap();
        let b = UdpSocket::bind("127.0.0.1:0").unwrap();
        a.connect(b.local_addr().unwrap()).unwrap();
        b.connect(a.local_addr().unwrap()).unwrap();
        (
            Udp::new(a, 3, None, emu).unwrap(),
            Udp::new(b, 3, None, Emulation::default()).unwrap(),
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
            assert_eq!((k, bytes::read::<u64>(&p[..8])), (Kind::Ping, Some(i)));
        }
    }

    /// A drain takes every waiting datagram, in order, across batches (more than [`BATCH`]
    /// wait), and ends once the socket is empty; the next drain sees what came after.
    #[test]
    fn a_drain_takes_every_datagram_across_batches_and_the_next_sees_later_ones() {
        let (mut a, mut b) = pair(Emulation::default());
        let drain = |b: &mut Udp| {
            let mut got = Vec::new();
            while let Some((_, p)) = b.recv().unwrap() {
                got.push(bytes::read::<u64>(&p[..8]).unwrap());
            }
            got
        };
        for i in 0..(2 * BATCH as u64 + 3) {
            a.send(Kind::Ping, &[&i.to_ne_bytes(), &[0u8; 160]], 0)
                .unwrap();
        }
        std::thread::sleep(std::time::Duration::from_millis(20));
        assert_eq!(drain(&mut b), (0..2 * BATCH as u64 + 3).collect::<Vec<_>>());
        assert_eq!(drain(&mut b), Vec::<u64>::new());
        a.send(Kind::Ping, &[&99u64.to_ne_bytes(), &[0u8; 160]], 0)
            .unwrap();
        std::thread::sleep(std::time::Duration::from_millis(20));
        assert_eq!(drain(&mut b), vec![99]);
    }

    /// A datagram's stamp is when it reached the socket, not when it was read: one read 30 ms
    /// after it came says so.
    #[test]
    fn a_datagram_is_stamped_with_its_arrival_not_its_reading() {
        let (mut a, mut b) = pair(Emulation::default());
        let sent = deltaloop_transport::rt::now_ns();
        a.send(Kind::Ping, &[&7u64.to_ne_bytes(), &[0u8; 160]], 0)
            .unwrap();
        std::thread::sleep(std::time::Duration::from_millis(30));
        let read = deltaloop_transport::rt::now_ns();
        let (_, _, at) = b.recv_stamped().unwrap().unwrap();
        let at = at.expect("the kernel stamps UDP datagrams");
        assert!(
            at >= sent.saturating_sub(1_000_000) && at + 20_000_000 < read,
            "sent {sent}, stamped {at}, read {read}"
        );
    }

    /// An attacker on the path (a forwarder between the two ends, which reads every datagram):
    /// what it forwards as is opens; a copy it sends again, one with a byte flipped, one with
    /// another session id, one of another run sealed under other keys, and junk are refused,
    /// each counted under its reason, and never handed to the loop.
    #[test]
    fn forged_replayed_and_other_run_datagrams_are_refused_and_counted() {
        let session = Session::generate().unwrap();
        let far = UdpSocket::bind("127.0.0.1:0").unwrap();
        let tap = UdpSocket::bind("127.0.0.1:0").unwrap();
        let near = UdpSocket::bind("127.0.0.1:0").unwrap();
        far.connect(tap.local_addr().unwrap()).unwrap();
        near.connect(tap.local_addr().unwrap()).unwrap();
        let mut tx = Udp::sealed(far, &session, End::Far, Emulation::default()).unwrap();
        let mut rx = Udp::sealed(near, &session, End::Near, Emulation::default()).unwrap();
        let to_near = rx.sock.local_addr().unwrap();
        let relay = |tx: &mut Udp, i: u64| -> Vec<u8> {
            let mut buf = [0u8; MAX_DATAGRAM];
            tx.send(Kind::Ping, &[&i.to_ne_bytes(), &[0u8; 160]], 0)
                .unwrap();
            let n = tap.recv(&mut buf).unwrap();
            buf[..n].to_vec()
        };
        let recv_all = |rx: &mut Udp| {
            std::thread::sleep(std::time::Duration::from_millis(20));
            let mut got = Vec::new();
            while let Some((k, p)) = rx.recv().unwrap() {
                got.push((k, bytes::read::<u64>(&p[..8]).unwrap()));
            }
            got
        };
        let first = relay(&mut tx, 1);
        assert_eq!(first.len(), HEADER + 168 + TAG);
        assert_ne!(
            &first[HEADER..HEADER + 8],
            &1u64.to_ne_bytes(),
            "sealed on the wire"
        );
        tap.send_to(&first, to_near).unwrap();
        assert_eq!(recv_all(&mut rx), [(Kind::Ping, 1)]);
        // Replayed, forged, another session, another run's keys, junk.
        tap.send_to(&first, to_near).unwrap();
        let mut forged = relay(&mut tx, 2);
        forged[HEADER] ^= 0x40;
        tap.send_to(&forged, to_near).unwrap();
        let mut moved = relay(&mut tx, 3);
        moved[8] ^= 1;
        tap.send_to(&moved, to_near).unwrap();
        let mut other = Session::generate().unwrap();
        other.id = session.id;
        let (a, b) = (
            UdpSocket::bind("127.0.0.1:0").unwrap(),
            UdpSocket::bind("127.0.0.1:0").unwrap(),
        );
        a.connect(b.local_addr().unwrap()).unwrap();
        let mut stranger = Udp::sealed(a, &other, End::Far, Emulation::default()).unwrap();
        stranger
            .send(Kind::Ping, &[&9u64.to_ne_bytes(), &[0u8; 160]], 0)
            .unwrap();
        let mut buf = [0u8; MAX_DATAGRAM];
        let n = b.recv(&mut buf).unwrap();
        tap.send_to(&buf[..n], to_near).unwrap();
        tap.send_to(b"junk", to_near).unwrap();
        // And the honest next one still opens.
        let next = relay(&mut tx, 4);
        tap.send_to(&next, to_near).unwrap();
        assert_eq!(recv_all(&mut rx), [(Kind::Ping, 4)]);
        use crate::seal::Refusal::*;
        let count = |r: crate::seal::Refusal| rx.refused.counts[r as usize];
        assert_eq!(
            (
                count(Replayed),
                count(Forged),
                count(OtherRun),
                count(Malformed)
            ),
            (1, 2, 1, 1),
            "{}",
            rx.refused.describe()
        );
    }
    /// Regression: an ICMP port unreachable quoting the link's addresses (here the peer's
    /// host's own, sent while its port was closed; anyone who knows the addresses can send
    /// one) left an error on the connected socket, the next send failed with ECONNREFUSED and
    /// was taken for sent: the datagram was silently lost (40 % of the ticks under such a
    /// flood) and nothing counted. The send is made again, and the error counted.
    #[test]
    fn regression_an_icmp_error_does_not_drop_the_next_datagram_silently() {
        let a = UdpSocket::bind("127.0.0.1:0").unwrap();
        let b = UdpSocket::bind("127.0.0.1:0").unwrap();
        let b_addr = b.local_addr().unwrap();
        a.connect(b_addr).unwrap();
        let mut a = Udp::new(a, 3, None, Emulation::default()).unwrap();
        // The peer's port closed: this datagram draws the ICMP port unreachable.
        drop(b);
        a.send(Kind::Ping, &[&1u64.to_ne_bytes(), &[0u8; 160]], 0)
            .unwrap();
        std::thread::sleep(std::time::Duration::from_millis(20));
        // Open again: the next datagram must reach it.
        let b = UdpSocket::bind(b_addr).unwrap();
        b.connect(a.sock.local_addr().unwrap()).unwrap();
        let mut b = Udp::new(b, 3, None, Emulation::default()).unwrap();
        a.send(Kind::Ping, &[&2u64.to_ne_bytes(), &[0u8; 160]], 0)
            .unwrap();
        std::thread::sleep(std::time::Duration::from_millis(20));
        let got = b
            .recv()
            .unwrap()
            .map(|(k, p)| (k, bytes::read::<u64>(&p[..8])));
        assert_eq!(
            got,
            Some((Kind::Ping, Some(2))),
            "the datagram was not sent"
        );
        assert_eq!(a.icmp_errors, 1);
    }

    /// Regression: a datagram longer than the largest of the link was cut by the kernel to
    /// [`MAX_DATAGRAM`] bytes unnoticed and read as the datagram those bytes make (a copy of
    /// an honest one with bytes appended was counted "replayed"). It is refused as malformed,
    /// and one of exactly the largest size still opens.
    #[test]
    fn regression_an_oversized_datagram_is_refused_as_malformed() {
        let session = Session::generate().unwrap();
        let far = UdpSocket::bind("127.0.0.1:0").unwrap();
        let tap = UdpSocket::bind("127.0.0.1:0").unwrap();
        let near = UdpSocket::bind("127.0.0.1:0").unwrap();
        far.connect(tap.local_addr().unwrap()).unwrap();
        near.connect(tap.local_addr().unwrap()).unwrap();
        let mut tx = Udp::sealed(far, &session, End::Far, Emulation::default()).unwrap();
        let mut rx = Udp::sealed(near, &session, End::Near, Emulation::default()).unwrap();
        let to_near = rx.sock.local_addr().unwrap();
        let mut buf = [0u8; 2048];
        // The largest datagram: three reply entries.
        let payload = [5u8; crate::replies::COPIES * crate::replies::ENTRY];
        tx.send(Kind::Torque, &[&payload], 0).unwrap();
        let n = tap.recv(&mut buf).unwrap();
        assert_eq!(n, MAX_DATAGRAM);
        let honest = buf[..n].to_vec();
        // Bytes appended to a copy of it, then the honest one itself.
        let mut long = honest.clone();
        long.extend_from_slice(&[0u8; 100]);
        tap.send_to(&long, to_near).unwrap();
        tap.send_to(&honest, to_near).unwrap();
        std::thread::sleep(std::time::Duration::from_millis(20));
        let got = rx.recv().unwrap().map(|(k, p)| (k, p.len()));
        assert_eq!(got, Some((Kind::Torque, payload.len())));
        assert!(rx.recv().unwrap().is_none());
        use crate::seal::Refusal::*;
        let count = |r: crate::seal::Refusal| rx.refused.counts[r as usize];
        assert_eq!(
            (count(Malformed), count(Replayed), count(Forged)),
            (1, 0, 0),
            "{}",
            rx.refused.describe()
        );
        let why = rx.last_refusal.as_deref().unwrap_or("");
        assert!(why.contains("longer than"), "{why}");
    }
}
