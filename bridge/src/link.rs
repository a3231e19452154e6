//! The two sockets of a bridge: the loop's UDP socket (one datagram per state or torque, with the
//! optional emulated delay, jitter and loss applied where it is sent) and the control plane's TCP
//! stream (frames: a u32 length, then a header and payload), both non-blocking, waited on with
//! `ppoll` together with the iceoryx2 wake-up event.

use crate::frame::{self, HEADER, Kind, MAX_FRAME, TAG};
use crate::seal::{Channel, End, Opener, Sealer, Session};
use anyhow::{Result, bail};
use std::io::{ErrorKind, Read, Write};
use std::net::TcpStream;

pub use deltaloop_link::udp::{
    EMULATION_SPIN_NS, Emulation, Udp, event, readable, timeout_ns, wait,
};

/// The control plane: a TCP stream with an input buffer for whole frames and an output buffer
/// written as the socket takes it (never blocking the loop). Every frame is sealed; a frame that
/// does not open (forged, replayed, out of order, another run) ends the stream with an error.
pub struct Tcp {
    pub stream: TcpStream,
    session: u64,
    seal: Sealer,
    open: Opener,
    inbuf: Vec<u8>,
    in_len: usize,
    out: Vec<u8>,
    out_pos: usize,
    /// The peer closed the stream (or it failed).
    pub closed: bool,
}

impl Tcp {
    /// The control plane of a run's link after the handshake: sealed under `session` as end
    /// `me`.
    pub fn new(stream: TcpStream, session: &Session, me: End) -> Result<Self> {
        stream.set_nodelay(true)?;
        stream.set_nonblocking(true)?;
        stream.set_read_timeout(None)?;
        stream.set_write_timeout(None)?;
        Ok(Self {
            stream,
            session: session.id,
            seal: session.sealer(me, Channel::Tcp),
            open: session.opener(me, Channel::Tcp),
            inbuf: vec![0; 4 + MAX_FRAME],
            in_len: 0,
            out: Vec::with_capacity(4 * (HEADER + MAX_FRAME)),
            out_pos: 0,
            closed: false,
        })
    }

    /// Bytes queued and not yet written.
    pub fn pending(&self) -> usize {
        self.out.len() - self.out_pos
    }

    /// Queues a frame of `kind` and writes what the socket takes now.
    pub fn send(&mut self, kind: Kind, parts: &[&[u8]]) -> Result<()> {
        self.queue(kind, parts)?;
        self.flush()
    }

    /// Queues a frame of `kind`, sealed, written by the next [`Tcp::flush`] or send. What is
    /// already written is dropped from the front first when the frame would not fit the buffer
    /// otherwise, so a steady stream (a remote plant's telemetry) stays in the pre-allocated
    /// buffer. A frame that still does not fit is an error: the peer has taken nothing for
    /// seconds (regression: the buffer grew without bound, on the tick path). After the stream
    /// closed, frames are dropped: there is no one to take them.
    pub fn queue(&mut self, kind: Kind, parts: &[&[u8]]) -> Result<()> {
        if self.closed {
            return Ok(());
        }
        let body: usize = parts.iter().map(|p| p.len()).sum();
        let len = HEADER + body + TAG;
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
        frame::put_header(
            &mut self.out[at..],
            kind,
            self.session,
            self.seal.next_counter(),
        );
        for p in parts {
            self.out.extend_from_slice(p);
        }
        let (head, body) = self.out[at..].split_at_mut(HEADER);
        let tag = self.seal.seal(head, body);
        self.out.extend_from_slice(&tag);
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

    /// Reads what has arrived and hands every whole frame to `f` (kind, opened payload). A frame
    /// that is malformed or does not open ends the stream with an error naming it.
    pub fn poll(&mut self, mut f: impl FnMut(Kind, &[u8]) -> Result<()>) -> Result<()> {
        self.poll_until(|k, p| f(k, p).map(|()| false))
    }

    /// Whether bytes that arrived are still held, not yet handed on (after
    /// [`Tcp::poll_until`] stopped early): the next poll must come without waiting for the socket.
    pub fn held(&self) -> bool {
        if self.in_len < 4 {
            return false;
        }
        let mut l = [0u8; 4];
        l.copy_from_slice(&self.inbuf[..4]);
        self.in_len - 4 >= u32::from_ne_bytes(l) as usize
    }

    /// [`Tcp::poll`], stopping after the frame for which `f` says true: the frames after it stay
    /// for the next poll (regression: the far controller's READY, in the same read as the ACK
    /// the handshake waited for, was dropped).
    pub fn poll_until(&mut self, mut f: impl FnMut(Kind, &[u8]) -> Result<bool>) -> Result<()> {
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
            if !(HEADER + TAG..=MAX_FRAME).contains(&len) {
                bail!(
                    "control frame of {len} bytes (allowed {}..={MAX_FRAME})",
                    HEADER + TAG
                );
            }
            if self.in_len - at - 4 < len {
                break;
            }
            let b = &mut self.inbuf[at + 4..at + 4 + len];
            let (kind, n) = deltaloop_link::udp::open(b, self.session, Some(&mut self.open))
                .map_err(|(_, why)| anyhow::anyhow!("control frame refused: {why}"))?;
            let stop = f(kind, &self.inbuf[at + 4 + HEADER..at + 4 + HEADER + n])?;
            at += 4 + len;
            if stop {
                break;
            }
        }
        self.inbuf.copy_within(at..self.in_len, 0);
        self.in_len -= at;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::seal::{End, Session};

    /// Regression: the far controller's READY came in the same read as the ACK, and the near
    /// side's wait for the ACK dropped it (the run then waited 30 s for a READY that had come).
    /// `poll_until` stops after the ACK and the READY stays for the next poll.
    #[test]
    fn regression_a_frame_in_the_same_read_as_the_ack_is_kept() {
        let l = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
        let c = TcpStream::connect(l.local_addr().unwrap()).unwrap();
        let (sv, _) = l.accept().unwrap();
        let session = Session::generate().unwrap();
        let mut far = Tcp::new(c, &session, End::Far).unwrap();
        let mut near = Tcp::new(sv, &session, End::Near).unwrap();
        far.queue(Kind::Ack, &[&7u64.to_ne_bytes()]).unwrap();
        far.queue(Kind::Log, &[b"READY"]).unwrap();
        far.flush().unwrap();
        std::thread::sleep(std::time::Duration::from_millis(50));
        let mut seen = Vec::new();
        near.poll_until(|k, _| {
            seen.push(k);
            Ok(k == Kind::Ack)
        })
        .unwrap();
        assert_eq!(seen, [Kind::Ack]);
        assert!(near.held());
        near.poll(|k, p| {
            seen.push(k);
            assert_eq!(p, b"READY");
            Ok(())
        })
        .unwrap();
        assert_eq!(seen, [Kind::Ack, Kind::Log]);
        assert!(!near.held());
    }
}
