//! The link's security: a pre-shared link key, a Noise handshake that proves both sides hold it
//! before either says anything of the run, and per-run session keys that seal every TCP frame and
//! every UDP datagram with ChaCha20-Poly1305 (`ring`'s, a few hundred ns a datagram; the pure-Rust
//! crate measured 13× slower on this machine).
//!
//! - **Handshake**: `Noise_NNpsk0_25519_ChaChaPoly_BLAKE2s` (the Noise framework with a
//!   pre-shared key, as WireGuard mixes its PSK; `snow`), prologue [`PROLOGUE`]. The far side
//!   (`join`) initiates: its first message is authenticated with the link key, so the near side
//!   drops a stranger before it sends a byte. The near side answers with fresh ephemeral
//!   Diffie-Hellman, and its answer's payload, encrypted under keys only the two ends can have,
//!   carries the run's [`Session`]: a random session id and four random 256-bit keys, one per
//!   channel and direction. A replayed first message gets that answer but cannot open it, so it
//!   cannot send the sealed first frame the near side waits for before it gives up its slot.
//! - **Sealing**: each message is `header ‖ ciphertext ‖ tag`; the header (magic, kind, session
//!   id, a 64-bit counter) is the associated data, the nonce is the counter, and each key's
//!   counter starts at 0 and only grows, so a nonce never repeats under a key. TCP frames must come
//!   in order, counter by counter; UDP datagrams pass a 1024-wide replay window (RFC 6479 style).
//!
//! Nothing here allocates after set-up; sealing and opening work in place.

pub use deltaloop_link::seal::*;
pub use deltaloop_link_setup::{
    KEY_ENV, LinkKey, LinkReport, RefusedCounts, SECRET_ENV, SideRefusals, scrub_secrets,
};
use std::io::{Read, Write};
use std::net::TcpStream;
use std::time::{Duration, Instant};

/// The Noise protocol of the handshake.
pub const NOISE: &str = "Noise_NNpsk0_25519_ChaChaPoly_BLAKE2s";
/// The link protocol's version: bound into the handshake ([`PROLOGUE`]) and said in the clear
/// before it ([`VERSION_MAGIC`]), so two versions name each other instead of failing as a wrong
/// key would. Raised with any change to the handshake, a frame's kind or layout.
pub const LINK_VERSION: u16 = 5;
/// Bound into the handshake: a peer of another protocol or version fails it.
pub const PROLOGUE: &[u8] = b"deltaloop link v5";
/// What the far side sends before its first handshake message, then [`LINK_VERSION`] (`u16`,
/// LE).
pub const VERSION_MAGIC: [u8; 4] = *b"DLLK";
/// The length a near side of another version answers with in place of a handshake message,
/// followed by its own [`LINK_VERSION`] (`u16`, LE).
const OTHER_VERSION: u16 = u16::MAX;
/// The length a near side answers with in place of its handshake message when the far side's
/// first message did not authenticate (another link key): the far side stops trying at once
/// instead of taking the closed connection for a busy or flooded near side. Like the busy
/// notice it proves nothing (anyone on the path could send it, as anyone could reset the
/// connection).
const REFUSED: u16 = u16::MAX - 1;
/// How long a connection has, all told, for the handshake's two messages (and, on the near
/// side, the far side's first sealed frame): one deadline from the connection's start, never
/// restarted by a byte, so a peer that trickles bytes holds a slot no longer than this.
pub const HANDSHAKE_BUDGET: Duration = Duration::from_secs(2);

/// Why a handshake failed: one line.
#[derive(Debug, PartialEq, Eq)]
pub enum HandshakeError {
    /// The peer does not hold this link key (or speaks another protocol).
    WrongKey,
    /// The peer closed the connection: a near side drops one whose key fails, but also one it
    /// had no time for (loaded, or flooded past its deadline), so this says nothing of the key.
    Closed,
    /// The peer did not finish within the deadline.
    Timeout,
    /// The near side was authenticating as many connections as it hears at once and dropped
    /// this one unheard (a flood of connections without the key?): try again.
    Busy,
    /// The peer speaks another version of the link (`Some`: which; None: no version this one
    /// knows how to read, an older deltaloop or not deltaloop at all).
    OtherVersion(Option<u16>),
    /// Anything else (I/O, a malformed message).
    Other(String),
}

impl std::fmt::Display for HandshakeError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            HandshakeError::WrongKey => write!(
                f,
                "failed authentication: it does not hold this link key (or is not a deltaloop link)"
            ),
            HandshakeError::Closed => write!(f, "closed the connection during the handshake"),
            HandshakeError::Timeout => write!(
                f,
                "did not complete the handshake within {} s",
                HANDSHAKE_BUDGET.as_secs()
            ),
            HandshakeError::Busy => write!(
                f,
                "is busy authenticating other connections (a flood of connections, perhaps) and dropped this one unheard"
            ),
            HandshakeError::OtherVersion(Some(v)) => write!(
                f,
                "speaks link version {v} and this side {LINK_VERSION}: another version of deltaloop (run the same version on both hosts)"
            ),
            HandshakeError::OtherVersion(None) => write!(
                f,
                "did not open with link version {LINK_VERSION}: another version of deltaloop (run the same version on both hosts), or not deltaloop"
            ),
            HandshakeError::Other(e) => write!(f, "handshake failed: {e}"),
        }
    }
}

/// Handshake messages are framed as a u16 length, then the Noise message.
const MAX_HANDSHAKE: usize = 256;

fn io_err(e: std::io::Error) -> HandshakeError {
    match e.kind() {
        std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut => HandshakeError::Timeout,
        std::io::ErrorKind::UnexpectedEof
        | std::io::ErrorKind::ConnectionReset
        | std::io::ErrorKind::BrokenPipe => HandshakeError::Closed,
        _ => HandshakeError::Other(e.to_string()),
    }
}

/// The time left until `end` (at least 1 ms: a zero timeout means none to the socket), or
/// [`HandshakeError::Timeout`] once it has passed.
fn left(end: Instant) -> Result<Duration, HandshakeError> {
    let now = Instant::now();
    if now >= end {
        return Err(HandshakeError::Timeout);
    }
    Ok((end - now).max(Duration::from_millis(1)))
}

/// Reads `buf` whole by `end`: each read waits only for what is left of the one deadline
/// (regression: a per-read timeout that every byte restarted let a peer sending a byte every
/// 4.5 s hold a connection for the whole wait).
fn read_exact_by(
    s: &mut TcpStream,
    mut buf: &mut [u8],
    end: Instant,
) -> Result<(), HandshakeError> {
    while !buf.is_empty() {
        s.set_read_timeout(Some(left(end)?)).map_err(io_err)?;
        match s.read(buf) {
            Ok(0) => return Err(HandshakeError::Closed),
            Ok(n) => buf = &mut buf[n..],
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
            Err(e) => return Err(io_err(e)),
        }
    }
    Ok(())
}

/// Writes `buf` whole by `end` (see [`read_exact_by`]).
fn write_all_by(s: &mut TcpStream, mut buf: &[u8], end: Instant) -> Result<(), HandshakeError> {
    while !buf.is_empty() {
        s.set_write_timeout(Some(left(end)?)).map_err(io_err)?;
        match s.write(buf) {
            Ok(0) => return Err(HandshakeError::Closed),
            Ok(n) => buf = &buf[n..],
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
            Err(e) => return Err(io_err(e)),
        }
    }
    Ok(())
}

fn send_msg(s: &mut TcpStream, m: &[u8], end: Instant) -> Result<(), HandshakeError> {
    let mut b = [0u8; 2 + MAX_HANDSHAKE];
    b[..2].copy_from_slice(&(m.len() as u16).to_le_bytes());
    b[2..2 + m.len()].copy_from_slice(m);
    write_all_by(s, &b[..2 + m.len()], end)
}

/// One handshake message; an empty one is the near side's [`busy`] notice. A near side of
/// another version answers with [`OTHER_VERSION`] and its version.
fn recv_msg(
    s: &mut TcpStream,
    out: &mut [u8; MAX_HANDSHAKE],
    end: Instant,
) -> Result<usize, HandshakeError> {
    let mut l = [0u8; 2];
    read_exact_by(s, &mut l, end)?;
    match u16::from_le_bytes(l) {
        OTHER_VERSION => {
            read_exact_by(s, &mut l, end)?;
            return Err(HandshakeError::OtherVersion(Some(u16::from_le_bytes(l))));
        }
        REFUSED => return Err(HandshakeError::WrongKey),
        _ => {}
    }
    let n = u16::from_le_bytes(l) as usize;
    if n > MAX_HANDSHAKE {
        return Err(HandshakeError::WrongKey);
    }
    read_exact_by(s, &mut out[..n], end)?;
    Ok(n)
}

/// The near side's notice to a connection it drops unheard because it is authenticating as
/// many as it hears at once: an empty handshake message (no Noise message is empty). It proves
/// nothing (anyone on the path could send it, as anyone could reset the connection); the far
/// side only reads it as "try again", not as a wrong key. Best effort, never blocking.
pub fn busy(s: &TcpStream) {
    let _ = s.set_nonblocking(true);
    let _ = (&*s).write(&[0, 0]);
}

fn builder(key: &LinkKey) -> Result<snow::Builder<'_>, HandshakeError> {
    builder_of(key, PROLOGUE)
}

fn builder_of<'a>(
    key: &'a LinkKey,
    prologue: &'a [u8],
) -> Result<snow::Builder<'a>, HandshakeError> {
    let params = NOISE
        .parse()
        .map_err(|e: snow::Error| HandshakeError::Other(e.to_string()))?;
    snow::Builder::new(params)
        .prologue(prologue)
        .and_then(|b| b.psk(0, key.bytes()))
        .map_err(|e| HandshakeError::Other(e.to_string()))
}

/// Makes the stream blocking; the deadline `timeout` from now, for the whole handshake.
fn deadline(s: &TcpStream, timeout: Duration) -> Result<Instant, HandshakeError> {
    s.set_nonblocking(false).map_err(io_err)?;
    Ok(Instant::now() + timeout)
}

/// The near side's handshake on an accepted connection: checks the far side's version and first
/// message (the link key), answers with `session` sealed to it (or, to a far side of another
/// version, with this side's version). The caller then waits for the far side's
/// first sealed frame before it believes the connection. `timeout`: for the whole handshake.
pub fn respond(
    s: &mut TcpStream,
    key: &LinkKey,
    session: &Session,
    timeout: Duration,
) -> Result<(), HandshakeError> {
    let end = deadline(s, timeout)?;
    let mut hs = builder(key)?
        .build_responder()
        .map_err(|e| HandshakeError::Other(e.to_string()))?;
    let mut said = [0u8; 6];
    read_exact_by(s, &mut said, end)?;
    if said[..4] != VERSION_MAGIC {
        return Err(HandshakeError::OtherVersion(None));
    }
    let version = u16::from_le_bytes([said[4], said[5]]);
    if version != LINK_VERSION {
        // Tells the far side which version this is, so it can name both; best effort.
        let notice = [OTHER_VERSION.to_le_bytes(), LINK_VERSION.to_le_bytes()].concat();
        let _ = write_all_by(s, &notice, end);
        return Err(HandshakeError::OtherVersion(Some(version)));
    }
    let (mut m, mut p) = ([0u8; MAX_HANDSHAKE], [0u8; MAX_HANDSHAKE]);
    let n = recv_msg(s, &mut m, end)?;
    if hs.read_message(&m[..n], &mut p).is_err() {
        // Says so, best effort: the far side then names the key at once (see [`REFUSED`]).
        let _ = write_all_by(s, &REFUSED.to_le_bytes(), end);
        return Err(HandshakeError::WrongKey);
    }
    let n = hs
        .write_message(&session.encode(), &mut m)
        .map_err(|e| HandshakeError::Other(e.to_string()))?;
    send_msg(s, &m[..n], end)
}

/// The far side's handshake on its connection: proves the link key, and takes the session the
/// near side sealed to it (which only a near side holding the key can send). `timeout`: for the
/// whole handshake.
pub fn initiate(
    s: &mut TcpStream,
    key: &LinkKey,
    timeout: Duration,
) -> Result<Session, HandshakeError> {
    let end = deadline(s, timeout)?;
    let mut hs = builder(key)?
        .build_initiator()
        .map_err(|e| HandshakeError::Other(e.to_string()))?;
    let (mut m, mut p) = ([0u8; MAX_HANDSHAKE], [0u8; MAX_HANDSHAKE]);
    let n = hs
        .write_message(&[], &mut m)
        .map_err(|e| HandshakeError::Other(e.to_string()))?;
    // The version and the message in one write: a near side that closes at once (busy) has
    // still sent its notice, which a second write would cut short with a reset.
    let mut b = [0u8; 6 + 2 + MAX_HANDSHAKE];
    b[..4].copy_from_slice(&VERSION_MAGIC);
    b[4..6].copy_from_slice(&LINK_VERSION.to_le_bytes());
    b[6..8].copy_from_slice(&(n as u16).to_le_bytes());
    b[8..8 + n].copy_from_slice(&m[..n]);
    write_all_by(s, &b[..8 + n], end)?;
    let n = recv_msg(s, &mut m, end)?;
    if n == 0 {
        return Err(HandshakeError::Busy);
    }
    let got = hs
        .read_message(&m[..n], &mut p)
        .map_err(|_| HandshakeError::WrongKey)?;
    Session::decode(&p[..got]).ok_or(HandshakeError::WrongKey)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::net::TcpListener;

    fn pair() -> (TcpStream, TcpStream) {
        let l = TcpListener::bind("127.0.0.1:0").unwrap();
        let c = TcpStream::connect(l.local_addr().unwrap()).unwrap();
        let (s, _) = l.accept().unwrap();
        (c, s)
    }

    fn handshake(
        near: &LinkKey,
        far: &LinkKey,
    ) -> (Result<(), HandshakeError>, Result<Session, HandshakeError>) {
        let (mut c, mut s) = pair();
        let session = Session::generate().unwrap();
        let near = near.clone();
        let t = std::thread::spawn(move || {
            let r = respond(&mut s, &near, &session, Duration::from_secs(2));
            drop(s);
            r
        });
        let f = initiate(&mut c, far, Duration::from_secs(2));
        (t.join().unwrap(), f)
    }

    /// Regression: the handshake's timeout was per read, and each byte restarted it: a peer
    /// sending one byte every 4.5 s held a near side's slot for 29 s, and a fake near side
    /// answering byte by byte held `join` for 27 s. One deadline covers the whole handshake, on
    /// both sides, however the peer paces its bytes.
    #[test]
    fn regression_a_peer_trickling_bytes_meets_one_deadline_for_the_handshake() {
        let key = LinkKey::generate().unwrap();
        let budget = Duration::from_millis(600);
        // Sends `bytes` one at a time, 150 ms apart, until the other side hangs up.
        let trickle = |mut s: TcpStream, bytes: Vec<u8>| {
            std::thread::spawn(move || {
                for b in bytes {
                    std::thread::sleep(Duration::from_millis(150));
                    if s.write_all(&[b]).is_err() {
                        return;
                    }
                }
            })
        };
        // Against the near side: a first message that is all there, a byte at a time.
        let (c, mut s) = pair();
        let t = trickle(c, [&48u16.to_le_bytes()[..], &[7u8; 48]].concat());
        let t0 = Instant::now();
        let r = respond(&mut s, &key, &Session::generate().unwrap(), budget);
        let took = t0.elapsed();
        drop(s);
        t.join().unwrap();
        assert_eq!(r, Err(HandshakeError::Timeout));
        // What this guards against took 27 to 29 s; 1 s leaves room for a loaded machine.
        assert!(took < budget + Duration::from_secs(1), "{took:?}");
        // Against the far side: a fake near side answering a byte at a time.
        let (mut c, s) = pair();
        let t = trickle(s, [&200u16.to_le_bytes()[..], &[1u8; 200]].concat());
        let t0 = Instant::now();
        let r = initiate(&mut c, &key, budget);
        let took = t0.elapsed();
        drop(c);
        t.join().unwrap();
        assert_eq!(r.err(), Some(HandshakeError::Timeout));
        assert!(took < budget + Duration::from_secs(1), "{took:?}");
    }

    /// Regression: the link's frames and handshake changed (the busy notice, RECALL, REFUSED, the
    /// reply entries' sequence numbers) under the same prologue, so a peer of the older version
    /// got as far as the run and failed there, or was taken for a wrong key. The version is
    /// bound into the handshake and said before it: two prologues never complete a handshake,
    /// and a peer of another version is named, with both versions, on both sides.
    #[test]
    fn regression_two_link_versions_do_not_complete_a_handshake_and_name_each_other() {
        assert_eq!(
            PROLOGUE,
            format!("deltaloop link v{LINK_VERSION}").as_bytes()
        );
        let key = LinkKey::generate().unwrap();
        // The bare handshake: the other prologue's first message does not open here.
        let mut far = builder_of(&key, b"deltaloop link v2")
            .unwrap()
            .build_initiator()
            .unwrap();
        let mut near = builder(&key).unwrap().build_responder().unwrap();
        let (mut m, mut p) = ([0u8; MAX_HANDSHAKE], [0u8; MAX_HANDSHAKE]);
        let n = far.write_message(&[], &mut m).unwrap();
        assert!(near.read_message(&m[..n], &mut p).is_err());
        // A far side of version 2 at this near side: refused naming it, and told this one.
        let (mut c, mut s) = pair();
        let t = std::thread::spawn(move || {
            let mut said = [0u8; 8];
            said[..4].copy_from_slice(&VERSION_MAGIC);
            said[4..6].copy_from_slice(&2u16.to_le_bytes());
            c.write_all(&said).unwrap();
            let mut heard = Vec::new();
            let _ = c.read_to_end(&mut heard);
            heard
        });
        let r = respond(
            &mut s,
            &key,
            &Session::generate().unwrap(),
            Duration::from_secs(2),
        );
        drop(s);
        assert_eq!(r, Err(HandshakeError::OtherVersion(Some(2))));
        let heard = t.join().unwrap();
        assert_eq!(
            heard,
            [&u16::MAX.to_le_bytes()[..], &LINK_VERSION.to_le_bytes()].concat()
        );
        // This far side at a near side of version 5: told so, one line naming both.
        let (mut c, mut s) = pair();
        s.write_all(&[0xff, 0xff, 5, 0]).unwrap();
        let e = initiate(&mut c, &key, Duration::from_secs(2))
            .err()
            .unwrap();
        assert_eq!(e, HandshakeError::OtherVersion(Some(5)));
        let line = e.to_string();
        assert!(
            line.contains(&format!("link version 5 and this side {LINK_VERSION}"))
                && line.contains("another version of deltaloop")
                && !line.contains('\n'),
            "{line}"
        );
        // Whatever does not open with the version: named too, not taken for a wrong key.
        let (mut c, mut s) = pair();
        c.write_all(&[&48u16.to_le_bytes()[..], &[7u8; 48]].concat())
            .unwrap();
        let r = respond(
            &mut s,
            &key,
            &Session::generate().unwrap(),
            Duration::from_secs(2),
        );
        assert_eq!(r, Err(HandshakeError::OtherVersion(None)));
        drop((c, s));
    }

    /// A connection the near side drops for want of room hears the busy notice: the far side
    /// says so, and does not blame the key.
    #[test]
    fn a_busy_near_side_is_not_taken_for_a_wrong_key() {
        let (mut c, s) = pair();
        busy(&s);
        drop(s);
        let r = initiate(
            &mut c,
            &LinkKey::generate().unwrap(),
            Duration::from_secs(2),
        );
        let Err(e) = r else {
            panic!("a busy notice opened a session")
        };
        assert_eq!(e, HandshakeError::Busy);
        assert!(!e.to_string().contains("link key"), "{e}");
    }

    #[test]
    fn both_sides_with_the_key_share_a_session_and_a_wrong_key_fails_both() {
        let k = LinkKey::generate().unwrap();
        let (n, f) = handshake(&k, &k);
        n.unwrap();
        let s = f.unwrap();
        assert_ne!(s.id, 0);
        let other = LinkKey::generate().unwrap();
        let (n, f) = handshake(&k, &other);
        assert_eq!(n, Err(HandshakeError::WrongKey));
        assert!(f.is_err());
    }

    /// Regression: a far side with another link key heard only a closed connection, which it
    /// takes for a busy or flooded near side and tries again until `--wait-s` (120 s) runs out.
    /// The near side says it refused the key, and the far side names the key at once.
    #[test]
    fn regression_a_far_side_with_another_key_is_told_so_at_once() {
        let (near, far) = (LinkKey::generate().unwrap(), LinkKey::generate().unwrap());
        let t0 = Instant::now();
        let (n, f) = handshake(&near, &far);
        assert_eq!(n, Err(HandshakeError::WrongKey));
        let Err(e) = f else {
            panic!("another key opened a session")
        };
        assert_eq!(e, HandshakeError::WrongKey);
        assert!(e.to_string().contains("link key"), "{e}");
        assert!(t0.elapsed() < Duration::from_secs(1), "{:?}", t0.elapsed());
    }

    /// Header, counter, and ciphertext followed by its tag.
    fn sealed(sealer: &mut Sealer, body: &[u8]) -> (Vec<u8>, u64, Vec<u8>) {
        let c = sealer.next_counter();
        let header = [b'H', 1, 2, 3]
            .iter()
            .copied()
            .chain(c.to_le_bytes())
            .collect::<Vec<_>>();
        let mut b = body.to_vec();
        let tag = sealer.seal(&header, &mut b);
        b.extend_from_slice(&tag);
        (header, c, b)
    }

    /// Opens a copy; the plaintext.
    fn open(rx: &mut Opener, (h, c, b): &(Vec<u8>, u64, Vec<u8>)) -> Result<Vec<u8>, Refusal> {
        let mut b = b.clone();
        let n = rx.open(h, *c, &mut b)?;
        Ok(b[..n].to_vec())
    }

    #[test]
    fn udp_opens_in_any_order_within_the_window_once_and_refuses_forgeries() {
        let s = Session::generate().unwrap();
        let mut tx = s.sealer(End::Far, Channel::Udp);
        let mut rx = s.opener(End::Near, Channel::Udp);
        let msgs: Vec<_> = (0..5).map(|i| sealed(&mut tx, &[i; 40])).collect();
        assert_ne!(msgs[0].2[..40], [0u8; 40], "encrypted");
        for i in [1usize, 0, 4, 2] {
            assert_eq!(open(&mut rx, &msgs[i]), Ok(vec![i as u8; 40]));
        }
        assert_eq!(open(&mut rx, &msgs[4]), Err(Refusal::Replayed));
        let mut forged = msgs[3].clone();
        forged.2[40] ^= 1;
        assert_eq!(open(&mut rx, &forged), Err(Refusal::Forged));
        let mut rebound = msgs[3].clone();
        rebound.0[1] ^= 1;
        assert_eq!(
            open(&mut rx, &rebound),
            Err(Refusal::Forged),
            "header bound"
        );
        assert_eq!(
            open(&mut rx, &msgs[3]),
            Ok(vec![3; 40]),
            "a forgery burns nothing"
        );
        // Far ahead, then one older than the window: refused as replayed.
        let mut last = None;
        for _ in 0..2000 {
            last = Some(sealed(&mut tx, &[9; 8]));
        }
        assert!(open(&mut rx, &last.unwrap()).is_ok());
        assert_eq!(open(&mut rx, &msgs[0]), Err(Refusal::Replayed));
        // The other direction's key does not open it.
        let mut wrong = s.opener(End::Far, Channel::Udp);
        assert_eq!(
            open(&mut wrong, &sealed(&mut tx, &[1; 8])),
            Err(Refusal::Forged)
        );
    }

    #[test]
    fn tcp_opens_strictly_in_order() {
        let s = Session::generate().unwrap();
        let mut tx = s.sealer(End::Near, Channel::Tcp);
        let mut rx = s.opener(End::Far, Channel::Tcp);
        let a = sealed(&mut tx, b"first");
        let b = sealed(&mut tx, b"second");
        assert_eq!(open(&mut rx, &b), Err(Refusal::Replayed));
        assert_eq!(open(&mut rx, &a), Ok(b"first".to_vec()));
        assert_eq!(open(&mut rx, &b), Ok(b"second".to_vec()));
    }
}
