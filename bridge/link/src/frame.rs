//! The link's wire format: what crosses between the two hosts. Every datagram (UDP, the loop) and
//! every frame (TCP, the control plane) starts with the same 24-byte header: magic `DLB2`, a
//! kind, the run's session id and the message's counter; then its payload, sealed, and the
//! 16-byte AEAD tag ([`crate::seal`]: the header is authenticated with it, the counter is the
//! nonce). A message of another run, another program or another byte order is dropped before
//! any decryption. The payloads are the `#[repr(C)]` wire types of `deltaloop_transport::wire`,
//! byte for byte (encrypted in place: shared memory → socket buffer, socket buffer → shared
//! memory). Both hosts must have the same byte order (checked by the magic).

use deltaloop_transport::wire::{ControlMsg, RefSample, StateMsg, TelemetryMsg};

/// `DLB2`, read as a native u32: a host of the other byte order reads `2BLD` and drops it (and a
/// peer of the unsealed link, `DLB1`, is told it is of another version).
pub const MAGIC: u32 = u32::from_ne_bytes(*b"DLB2");
/// Header bytes before every payload.
pub const HEADER: usize = 24;
/// Bytes after every sealed payload: the AEAD tag.
pub const TAG: usize = crate::seal::TAG_LEN;
/// The largest TCP frame (after its u32 length): the HELLO's config text or a reference chunk.
pub const MAX_FRAME: usize = 1 << 20;
/// The largest datagram the loop sends, bytes (three replies: header + 3 × 152 + tag; a state
/// is header + 168 + tag).
pub const MAX_DATAGRAM: usize = HEADER + crate::replies::COPIES * crate::replies::ENTRY + TAG;

/// What a datagram or frame carries.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(u16)]
pub enum Kind {
    /// UDP, near → far: one `StateMsg`.
    State = 1,
    /// UDP, far → near: the newest reply and up to two before it, each a `TorqueMsg` and the far
    /// side's residence time (u64, ns), newest first ([`crate::replies`]).
    Torque = 2,
    /// UDP: bench ping (u64 sequence, then padding to a state's size) and its echo.
    Ping = 3,
    Pong = 4,
    /// UDP, far → near: opens the far host's firewall for the near side's datagrams; no payload.
    Punch = 5,
    /// TCP, near → far: the run (see [`Hello`]).
    Hello = 16,
    /// TCP, far → near: the far UDP port (u64).
    Ack = 17,
    /// TCP, both ways: one `ControlMsg` (START's `t0_ns` is relative on the wire: ns from the
    /// send to tick 0's deadline).
    Control = 18,
    /// TCP, near → far: one reference chunk, `[RefSample]`.
    Reference = 19,
    /// TCP, near → far: the final state (`STATE_FINAL`), reliably.
    Final = 20,
    /// TCP, far → near: the far process's exit code (u32) and its last stderr line.
    Exit = 21,
    /// TCP, far → near: one line of the far process's stderr.
    Log = 22,
    /// TCP, far → near (remote plant): one `TelemetryMsg`.
    Telemetry = 23,
    /// TCP, far → near, the first sealed frame after the handshake: which role the far side
    /// joined for (u32: the `RemoteSide` as 1 controller, 2 plant). It proves the far side holds
    /// the session; the near side says nothing of the run before it.
    Join = 24,
    /// TCP, far → near, at the end of a run before EXIT: the datagrams the far side refused,
    /// by reason, and the ICMP-reported errors on its socket (five u64, little-endian:
    /// malformed, other run, forged, replayed, ICMP errors), for the run's record on the
    /// supervisor's host.
    Refused = 25,
    /// TCP, near → far: replies lost beyond the copies, wanted again (two u64: the first
    /// sequence number and how many, 1..=[`crate::replies::RING`]; [`crate::replies`]).
    Recall = 26,
    /// TCP, far → near: the answer to a RECALL (its two u64, then the entries of those replies
    /// still in the far side's ring, oldest first).
    Recalled = 27,
    /// TCP, far → near (remote controller on the direct path): the far controller's replies
    /// for the record on the supervisor's host, every one, oldest first, each an entry as in a
    /// Torque datagram (`TorqueMsg`, residence, sequence number), 1..=[`MAX_REPLIES`] a frame.
    Replies = 28,
    /// TCP, near → far (remote controller), before START: the plant took the link's socket (the
    /// direct path), so the record on the near host needs a copy of each reply ([`Kind::Replies`])
    /// whichever path this side takes. No payload.
    NearDirect = 29,
}

/// Replies in one [`Kind::Replies`] frame at most.
pub const MAX_REPLIES: usize = 1024;

impl Kind {
    fn from_wire(v: u16) -> Option<Self> {
        use Kind::*;
        [
            State, Torque, Ping, Pong, Punch, Hello, Ack, Control, Reference, Final, Exit, Log,
            Telemetry, Join, Refused, Recall, Recalled, Replies, NearDirect,
        ]
        .into_iter()
        .find(|k| *k as u16 == v)
    }
}

/// Writes the header of a `kind` message of session `session`, counter `counter`, into
/// `out[..HEADER]`.
pub fn put_header(out: &mut [u8], kind: Kind, session: u64, counter: u64) {
    out[0..4].copy_from_slice(&MAGIC.to_ne_bytes());
    out[4..6].copy_from_slice(&(kind as u16).to_ne_bytes());
    out[6..8].copy_from_slice(&0u16.to_ne_bytes());
    out[8..16].copy_from_slice(&session.to_ne_bytes());
    out[16..24].copy_from_slice(&counter.to_le_bytes());
}

/// Why a datagram or frame was refused: one line.
#[derive(Debug, PartialEq, Eq)]
pub enum Refused {
    Short(usize),
    Magic,
    Kind(u16),
    Run,
    Size { kind: Kind, got: usize },
}

impl Refused {
    /// The reason it is counted under.
    pub fn reason(&self) -> crate::seal::Refusal {
        match self {
            Refused::Run => crate::seal::Refusal::OtherRun,
            _ => crate::seal::Refusal::Malformed,
        }
    }
}

impl std::fmt::Display for Refused {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Refused::Short(n) => write!(f, "{n} bytes, shorter than the {HEADER}-byte header"),
            Refused::Magic => write!(
                f,
                "not a message of this deltaloop link version (magic is not DLB2)"
            ),
            Refused::Kind(k) => write!(f, "unknown kind {k}"),
            Refused::Run => write!(f, "for another run (session id differs)"),
            Refused::Size { kind, got } => write!(f, "{kind:?} with a {got}-byte payload"),
        }
    }
}

/// The payload size a kind must have, if fixed.
fn fixed_size(kind: Kind) -> Option<usize> {
    match kind {
        Kind::State | Kind::Final => Some(size_of::<StateMsg>()),
        Kind::Ping | Kind::Pong => Some(size_of::<StateMsg>()),
        Kind::Punch | Kind::NearDirect => Some(0),
        Kind::Ack => Some(8),
        Kind::Refused => Some(5 * 8),
        Kind::Control => Some(size_of::<ControlMsg>()),
        Kind::Telemetry => Some(size_of::<TelemetryMsg>()),
        // A recall and its answer are checked by their reader, which refuses and counts a malformed
        // one instead of ending the link.
        Kind::Hello
        | Kind::Join
        | Kind::Reference
        | Kind::Exit
        | Kind::Log
        | Kind::Torque
        | Kind::Recall
        | Kind::Recalled
        | Kind::Replies => None,
    }
}

/// A message's header, read.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Head {
    pub kind: Kind,
    pub session: u64,
    pub counter: u64,
}

/// Reads the header of message `b` of session `session` (`None`: any). Never panics.
pub fn head(b: &[u8], session: Option<u64>) -> Result<Head, Refused> {
    if b.len() < HEADER {
        return Err(Refused::Short(b.len()));
    }
    let word = |r: std::ops::Range<usize>| {
        let mut a = [0u8; 8];
        a[..r.len()].copy_from_slice(&b[r]);
        a
    };
    if u32::from_ne_bytes(word(0..4)[..4].try_into().unwrap_or_default()) != MAGIC {
        return Err(Refused::Magic);
    }
    let raw = u16::from_ne_bytes([b[4], b[5]]);
    let kind = Kind::from_wire(raw).ok_or(Refused::Kind(raw))?;
    let id = u64::from_ne_bytes(word(8..16));
    if session.is_some_and(|s| s != id) {
        return Err(Refused::Run);
    }
    Ok(Head {
        kind,
        session: id,
        counter: u64::from_le_bytes(word(16..24)),
    })
}

/// Whether `payload` (opened) has a size `kind` allows.
pub fn check_size(kind: Kind, payload: &[u8]) -> Result<(), Refused> {
    let ok = match kind {
        Kind::Reference => {
            !payload.is_empty()
                && payload.len().is_multiple_of(size_of::<RefSample>())
                && payload.len() <= deltaloop_transport::ipc::REF_CHUNK * size_of::<RefSample>()
        }
        Kind::Exit => payload.len() >= 4,
        Kind::Torque => crate::replies::valid_len(payload.len()),
        Kind::Replies => {
            let e = crate::replies::ENTRY;
            !payload.is_empty()
                && payload.len().is_multiple_of(e)
                && payload.len() <= MAX_REPLIES * e
        }
        _ => fixed_size(kind).is_none_or(|n| n == payload.len()),
    };
    if ok {
        Ok(())
    } else {
        Err(Refused::Size {
            kind,
            got: payload.len(),
        })
    }
}

/// Checks an unsealed message (the bench's ping-pong) of session `session` and returns its kind
/// and payload. Never panics, whatever the bytes.
pub fn parse(b: &[u8], session: Option<u64>) -> Result<(Kind, &[u8]), Refused> {
    let h = head(b, session)?;
    let payload = &b[HEADER..];
    check_size(h.kind, payload)?;
    Ok((h.kind, payload))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bytes::{bytes_of, read};

    fn msg(kind: Kind, key: u64, payload: &[u8]) -> Vec<u8> {
        let mut v = vec![0u8; HEADER];
        put_header(&mut v, kind, key, 0);
        v.extend_from_slice(payload);
        v
    }

    #[test]
    fn a_state_round_trips_byte_for_byte() {
        let s = StateMsg {
            tick: 7,
            q: [0.1, -0.2, 0.3],
            t_publish_ns: 99,
            ..Default::default()
        };
        let m = msg(Kind::State, 5, bytes_of(&s));
        let (k, p) = parse(&m, Some(5)).unwrap();
        assert_eq!(k, Kind::State);
        assert_eq!(read::<StateMsg>(p), Some(s));
    }

    #[test]
    fn hostile_datagrams_are_refused_with_a_reason() {
        let s = StateMsg::default();
        assert_eq!(parse(&[1, 2, 3], Some(1)), Err(Refused::Short(3)));
        let mut m = msg(Kind::State, 1, bytes_of(&s));
        assert_eq!(parse(&m, Some(2)).unwrap_err(), Refused::Run);
        m.pop();
        assert!(matches!(
            parse(&m, Some(1)),
            Err(Refused::Size {
                kind: Kind::State,
                got: 167
            })
        ));
        assert_eq!(Refused::Run.reason(), crate::seal::Refusal::OtherRun);
        m[0] = b'X';
        assert_eq!(parse(&m, Some(1)).unwrap_err(), Refused::Magic);
        let mut m = msg(Kind::Ping, 1, &[0; 168]);
        m[4] = 200;
        assert_eq!(parse(&m, Some(1)).unwrap_err(), Refused::Kind(200));
        // A reference chunk must be whole rows, at most one chunk.
        assert!(parse(&msg(Kind::Reference, 1, &[0; 81]), Some(1)).is_err());
        assert!(parse(&msg(Kind::Reference, 1, &[0; 160]), Some(1)).is_ok());
        // Anything at all: never a panic.
        let mut x: u64 = 1;
        for n in 0..2000usize {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            let mut b: Vec<u8> = (0..n % 300).map(|i| (x >> (i % 56)) as u8).collect();
            if b.len() >= HEADER && n % 2 == 0 {
                put_header(
                    &mut b,
                    Kind::from_wire((n % 23) as u16).unwrap_or(Kind::State),
                    9,
                    n as u64,
                );
            }
            let _ = parse(&b, Some(9));
        }
    }
}
