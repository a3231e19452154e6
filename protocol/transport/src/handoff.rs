//! The hand-off between a bridge and the loop process beside it on one host: a private
//! `AF_UNIX` `SOCK_SEQPACKET` pair (one message per send, message boundaries kept), one end
//! inherited by the loop process, its number in [`FD_ENV`]. Over it the bridge gives a process
//! that asked for it the link's socket and this run's session keys for the loop's datagrams
//! ([`Tag::Offer`], the socket passed as `SCM_RIGHTS`), so plant and controller exchange state
//! and torque socket to socket, with no relay between them (docs/protocol.md §14.4). The
//! long-lived link key never crosses it, and nothing secret is ever in a loop process's
//! environment (the bridges hold the key in theirs).
//!
//! The exchange: the loop process says [`Tag::Hello`] at set-up (before its READY); at START the
//! bridge answers [`Tag::Offer`] (or [`Tag::Relay`]: the run asks for the relay); at its end the
//! process says [`Tag::Counts`] (what it refused and lost, for the run's link report). A process
//! that never says HELLO (one that speaks only iceoryx2, like the Python helper) is relayed as
//! before.

use std::io;
use std::os::fd::{AsRawFd, FromRawFd, OwnedFd, RawFd};

/// The environment variable that names the inherited end's descriptor number (not a secret:
/// only a process that inherited the descriptor can use it).
pub const FD_ENV: &str = "DELTALOOP_LINK_FD";

/// Largest message, bytes.
pub const MAX_MSG: usize = 512;

/// What a message is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(u8)]
pub enum Tag {
    /// Process → bridge: it takes the link's socket if offered (payload: the hand-off version).
    Hello = 1,
    /// Bridge → process: the socket (`SCM_RIGHTS`) and the sealing state (bridge's layout).
    Offer = 2,
    /// Bridge → process: no offer; the loop goes through the bridge (iceoryx2 as on one host).
    Relay = 3,
    /// Process → bridge, at its end: what its socket refused and lost (bridge's layout).
    Counts = 4,
}

impl Tag {
    fn of(b: u8) -> Option<Self> {
        Some(match b {
            1 => Tag::Hello,
            2 => Tag::Offer,
            3 => Tag::Relay,
            4 => Tag::Counts,
            _ => return None,
        })
    }
}

/// The hand-off version a HELLO carries; a bridge offers only to its own version.
pub const VERSION: u16 = 1;

/// One end of the pair.
#[derive(Debug)]
pub struct End(OwnedFd);

/// A fresh pair: (the bridge's end, the loop process's end), both close-on-exec (the loop
/// process's end is made inheritable only in its own child, [`inherit`]).
pub fn pair() -> io::Result<(End, End)> {
    let mut fds = [0 as RawFd; 2];
    // SAFETY: socketpair writes two descriptors into the array we own.
    let r = unsafe {
        libc::socketpair(
            libc::AF_UNIX,
            libc::SOCK_SEQPACKET | libc::SOCK_CLOEXEC,
            0,
            fds.as_mut_ptr(),
        )
    };
    if r != 0 {
        return Err(io::Error::last_os_error());
    }
    // SAFETY: both descriptors are new and ours.
    Ok(unsafe {
        (
            End(OwnedFd::from_raw_fd(fds[0])),
            End(OwnedFd::from_raw_fd(fds[1])),
        )
    })
}

/// Makes `end` the child's inherited end of `cmd`: its descriptor stays open across exec in the
/// child only, and [`FD_ENV`] names it. The parent keeps `end` until the child has started, then
/// drops it.
pub fn inherit(cmd: &mut std::process::Command, end: &End) {
    use std::os::unix::process::CommandExt;
    let fd = end.0.as_raw_fd();
    cmd.env(FD_ENV, fd.to_string());
    // SAFETY: fcntl is async-signal-safe; it only clears this descriptor's close-on-exec flag in
    // the forked child.
    unsafe {
        cmd.pre_exec(move || {
            if libc::fcntl(fd, libc::F_SETFD, 0) != 0 {
                return Err(io::Error::last_os_error());
            }
            Ok(())
        });
    }
}

impl End {
    /// The end this process inherited ([`FD_ENV`]), if it names an `AF_UNIX` seqpacket socket;
    /// the variable is removed, so a child of this process does not see it. None: no hand-off.
    pub fn inherited() -> Option<Self> {
        let v = std::env::var(FD_ENV).ok()?;
        // SAFETY: single-threaded at set-up, before any thread of ours reads the environment.
        unsafe { std::env::remove_var(FD_ENV) };
        let fd: RawFd = v.parse().ok().filter(|f| *f > 2)?;
        let (mut ty, mut len) = (
            0 as libc::c_int,
            size_of::<libc::c_int>() as libc::socklen_t,
        );
        // SAFETY: getsockopt writes an int we own; a descriptor that is not a socket fails.
        let r = unsafe {
            libc::getsockopt(
                fd,
                libc::SOL_SOCKET,
                libc::SO_TYPE,
                (&mut ty as *mut libc::c_int).cast(),
                &mut len,
            )
        };
        if r != 0 || ty != libc::SOCK_SEQPACKET {
            return None;
        }
        // SAFETY: the descriptor was inherited for us and nothing else owns it in this process.
        unsafe { libc::fcntl(fd, libc::F_SETFD, libc::FD_CLOEXEC) };
        Some(End(unsafe { OwnedFd::from_raw_fd(fd) }))
    }

    /// Sends one message (`tag`, `payload`), with descriptor `fd` attached if given.
    pub fn send(&self, tag: Tag, payload: &[u8], fd: Option<RawFd>) -> io::Result<()> {
        if payload.len() + 1 > MAX_MSG {
            return Err(io::Error::other("hand-off message too long"));
        }
        let mut buf = [0u8; MAX_MSG];
        buf[0] = tag as u8;
        buf[1..1 + payload.len()].copy_from_slice(payload);
        let mut iov = libc::iovec {
            iov_base: buf.as_mut_ptr().cast(),
            iov_len: 1 + payload.len(),
        };
        // Room for one descriptor's control message, aligned.
        let mut cbuf = [0u64; 4];
        // SAFETY: msghdr is plain data; zeroed is a valid empty header.
        let mut msg: libc::msghdr = unsafe { std::mem::zeroed() };
        msg.msg_iov = &mut iov;
        msg.msg_iovlen = 1;
        if let Some(fd) = fd {
            // SAFETY: CMSG_* compute within `cbuf`, which holds CMSG_SPACE(sizeof(int)) bytes.
            unsafe {
                let space = libc::CMSG_SPACE(size_of::<RawFd>() as u32) as usize;
                msg.msg_control = cbuf.as_mut_ptr().cast();
                msg.msg_controllen = space as _;
                let c = libc::CMSG_FIRSTHDR(&msg);
                (*c).cmsg_level = libc::SOL_SOCKET;
                (*c).cmsg_type = libc::SCM_RIGHTS;
                (*c).cmsg_len = libc::CMSG_LEN(size_of::<RawFd>() as u32) as _;
                std::ptr::write_unaligned(libc::CMSG_DATA(c).cast::<RawFd>(), fd);
            }
        }
        // SAFETY: msg points at buffers we own for the duration of the call.
        let r = unsafe { libc::sendmsg(self.0.as_raw_fd(), &msg, libc::MSG_NOSIGNAL) };
        if r < 0 {
            return Err(io::Error::last_os_error());
        }
        Ok(())
    }

    /// Receives one message within `timeout_ns` (0: only what is there now): its tag, payload
    /// (copied into `out`, its length returned) and the descriptor that came with it. None: no
    /// message in time, or the other end is closed. Unknown tags are skipped.
    pub fn recv(
        &self,
        out: &mut [u8; MAX_MSG],
        timeout_ns: u64,
    ) -> io::Result<Option<(Tag, usize, Option<OwnedFd>)>> {
        let end = crate::rt::now_ns().saturating_add(timeout_ns);
        loop {
            let left = end.saturating_sub(crate::rt::now_ns());
            let mut pfd = libc::pollfd {
                fd: self.0.as_raw_fd(),
                events: libc::POLLIN,
                revents: 0,
            };
            let ts = libc::timespec {
                tv_sec: (left / 1_000_000_000) as libc::time_t,
                tv_nsec: (left % 1_000_000_000) as libc::c_long,
            };
            // SAFETY: one pollfd and a timespec we own.
            let r = unsafe { libc::ppoll(&mut pfd, 1, &ts, std::ptr::null()) };
            if r < 0 {
                let e = io::Error::last_os_error();
                if e.kind() == io::ErrorKind::Interrupted {
                    continue;
                }
                return Err(e);
            }
            if r == 0 {
                return Ok(None);
            }
            let mut buf = [0u8; MAX_MSG];
            let mut iov = libc::iovec {
                iov_base: buf.as_mut_ptr().cast(),
                iov_len: MAX_MSG,
            };
            let mut cbuf = [0u64; 8];
            // SAFETY: as in `send`.
            let mut msg: libc::msghdr = unsafe { std::mem::zeroed() };
            msg.msg_iov = &mut iov;
            msg.msg_iovlen = 1;
            msg.msg_control = cbuf.as_mut_ptr().cast();
            msg.msg_controllen = size_of_val(&cbuf) as _;
            // SAFETY: msg points at buffers we own; MSG_CMSG_CLOEXEC keeps a received
            // descriptor from leaking into our own children.
            let n = unsafe {
                libc::recvmsg(
                    self.0.as_raw_fd(),
                    &mut msg,
                    libc::MSG_DONTWAIT | libc::MSG_CMSG_CLOEXEC,
                )
            };
            if n < 0 {
                let e = io::Error::last_os_error();
                if e.kind() == io::ErrorKind::WouldBlock {
                    continue;
                }
                return Err(e);
            }
            if n == 0 {
                return Ok(None);
            }
            let mut fd = None;
            // SAFETY: walking the control messages the kernel wrote into `cbuf`.
            unsafe {
                let mut c = libc::CMSG_FIRSTHDR(&msg);
                while !c.is_null() {
                    if (*c).cmsg_level == libc::SOL_SOCKET && (*c).cmsg_type == libc::SCM_RIGHTS {
                        let f = std::ptr::read_unaligned(libc::CMSG_DATA(c).cast::<RawFd>());
                        if fd.is_none() {
                            fd = Some(OwnedFd::from_raw_fd(f));
                        } else {
                            libc::close(f);
                        }
                    }
                    c = libc::CMSG_NXTHDR(&msg, c);
                }
            }
            let n = n as usize;
            let Some(tag) = Tag::of(buf[0]) else {
                continue;
            };
            out[..n - 1].copy_from_slice(&buf[1..n]);
            return Ok(Some((tag, n - 1, fd)));
        }
    }
}

impl AsRawFd for End {
    fn as_raw_fd(&self) -> RawFd {
        self.0.as_raw_fd()
    }
}
