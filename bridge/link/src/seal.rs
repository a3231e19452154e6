//! The link's sealing: per-run session keys that seal every TCP frame and every UDP datagram with
//! ChaCha20-Poly1305 (`ring`'s). Each message is `header ‖ ciphertext ‖ tag`; the header (magic,
//! kind, session id, a 64-bit counter) is the associated data, the nonce is the counter, and each
//! key's counter starts at 0 and only grows, so a nonce never repeats under a key. TCP frames must
//! come in order, counter by counter; UDP datagrams pass a 1024-wide replay window (RFC 6479
//! style). The handshake that makes a session is the bridge's.
//!
//! Nothing here allocates after set-up; sealing and opening work in place.

use ring::aead::{Aad, CHACHA20_POLY1305, LessSafeKey, Nonce, UnboundKey};

/// Bytes of a link key and of every session key.
pub use deltaloop_link_setup::KEY_LEN;
/// Bytes of the AEAD tag after every sealed message.
pub const TAG_LEN: usize = 16;
/// Width of the UDP replay window, datagrams.
pub const WINDOW: u64 = 1024;

pub use deltaloop_link_setup::random_bytes;

/// A run's session: its id (in every message's header) and one key per channel and direction,
/// all chosen at random by the near side for this run alone.
#[derive(Clone)]
pub struct Session {
    pub id: u64,
    keys: [[u8; KEY_LEN]; 4],
}

/// Which end of the link: the near side (the supervisor's host, which listens and answers the
/// handshake) or the far side (`join`, which connects and begins it).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum End {
    Near,
    Far,
}

/// The two channels a session seals.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Channel {
    Tcp,
    Udp,
}

impl Session {
    /// A fresh session (the near side makes it).
    pub fn generate() -> Result<Self, String> {
        Ok(Self {
            id: u64::from_ne_bytes(random_bytes()?),
            keys: [
                random_bytes()?,
                random_bytes()?,
                random_bytes()?,
                random_bytes()?,
            ],
        })
    }

    pub const WIRE: usize = 8 + 4 * KEY_LEN;

    pub fn encode(&self) -> [u8; Self::WIRE] {
        let mut b = [0u8; Self::WIRE];
        b[..8].copy_from_slice(&self.id.to_le_bytes());
        for (i, k) in self.keys.iter().enumerate() {
            b[8 + i * KEY_LEN..8 + (i + 1) * KEY_LEN].copy_from_slice(k);
        }
        b
    }

    pub fn decode(b: &[u8]) -> Option<Self> {
        (b.len() == Self::WIRE).then(|| {
            let mut keys = [[0u8; KEY_LEN]; 4];
            for (i, k) in keys.iter_mut().enumerate() {
                k.copy_from_slice(&b[8 + i * KEY_LEN..8 + (i + 1) * KEY_LEN]);
            }
            let mut id = [0u8; 8];
            id.copy_from_slice(&b[..8]);
            Self {
                id: u64::from_le_bytes(id),
                keys,
            }
        })
    }

    fn key(&self, channel: Channel, from: End) -> &[u8; KEY_LEN] {
        let i = match (channel, from) {
            (Channel::Tcp, End::Near) => 0,
            (Channel::Tcp, End::Far) => 1,
            (Channel::Udp, End::Near) => 2,
            (Channel::Udp, End::Far) => 3,
        };
        &self.keys[i]
    }

    /// The two keys of `me`'s datagrams: (what it seals with, what it opens with).
    pub fn udp_keys(&self, me: End) -> ([u8; KEY_LEN], [u8; KEY_LEN]) {
        let other = match me {
            End::Near => End::Far,
            End::Far => End::Near,
        };
        (*self.key(Channel::Udp, me), *self.key(Channel::Udp, other))
    }

    /// What `me` seals with on `channel`.
    pub fn sealer(&self, me: End, channel: Channel) -> Sealer {
        Sealer {
            aead: aead(self.key(channel, me)),
            next: 0,
        }
    }

    /// What `me` opens the other end's messages on `channel` with.
    pub fn opener(&self, me: End, channel: Channel) -> Opener {
        let from = match me {
            End::Near => End::Far,
            End::Far => End::Near,
        };
        Opener {
            aead: aead(self.key(channel, from)),
            window: Window::default(),
            strict: channel == Channel::Tcp,
        }
    }
}

/// A ChaCha20-Poly1305 key (32 bytes always make one).
fn aead(key: &[u8; KEY_LEN]) -> LessSafeKey {
    LessSafeKey::new(
        UnboundKey::new(&CHACHA20_POLY1305, key).unwrap_or_else(|_| unreachable!("32 bytes")),
    )
}

/// The nonce of message `counter`: 4 zero bytes and the counter, little-endian.
fn nonce(counter: u64) -> Nonce {
    let mut n = [0u8; 12];
    n[4..].copy_from_slice(&counter.to_le_bytes());
    Nonce::assume_unique_for_key(n)
}

/// Seals one direction of one channel: counter nonces from 0.
pub struct Sealer {
    aead: LessSafeKey,
    next: u64,
}

impl Sealer {
    /// A sealer of `key` whose next message gets counter `next` (a socket handed on: the
    /// counters go on where its last owner stopped, so no nonce repeats).
    pub fn resume(key: &[u8; KEY_LEN], next: u64) -> Self {
        Self {
            aead: aead(key),
            next,
        }
    }

    /// The counter the next message gets (its nonce): put it in the header first.
    pub fn next_counter(&self) -> u64 {
        self.next
    }

    /// Encrypts `body` in place under the next counter, authenticating `header` with it (which
    /// must carry that counter); returns the tag to append.
    pub fn seal(&mut self, header: &[u8], body: &mut [u8]) -> [u8; TAG_LEN] {
        let n = self.next;
        // A counter of 2⁶⁴ messages cannot be reached (at 3.3 kHz, 10¹¹ years).
        self.next += 1;
        let mut out = [0u8; TAG_LEN];
        if let Ok(tag) = self
            .aead
            .seal_in_place_separate_tag(nonce(n), Aad::from(header), body)
        {
            out.copy_from_slice(tag.as_ref());
        }
        out
    }
}

/// Why a sealed message was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Refusal {
    /// Not a message of this link: too short, not our magic, an unknown kind, a wrong size.
    Malformed,
    /// A session id of another run (or of another link).
    OtherRun,
    /// The tag does not verify: forged, corrupted, or sealed with another key.
    Forged,
    /// A counter already seen, or older than the replay window (or, on TCP, out of order).
    Replayed,
}

impl Refusal {
    /// Every reason, in the order of [`Refusals::counts`].
    pub const ALL: [Refusal; 4] = [
        Refusal::Malformed,
        Refusal::OtherRun,
        Refusal::Forged,
        Refusal::Replayed,
    ];

    /// The word (summary.json keys, messages).
    pub fn name(self) -> &'static str {
        match self {
            Refusal::Malformed => "malformed",
            Refusal::OtherRun => "other_run",
            Refusal::Forged => "forged",
            Refusal::Replayed => "replayed",
        }
    }
}

/// Refused messages counted by reason.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Refusals {
    pub counts: [u64; 4],
}

/// The counts by name, as the link report holds them.
impl From<Refusals> for deltaloop_link_setup::RefusedCounts {
    fn from(r: Refusals) -> Self {
        let [malformed, other_run, forged, replayed] = r.counts;
        Self {
            malformed,
            other_run,
            forged,
            replayed,
        }
    }
}

impl Refusals {
    pub fn add(&mut self, r: Refusal) {
        self.counts[r as usize] += 1;
    }

    pub fn total(&self) -> u64 {
        self.counts.iter().fold(0, |t, n| t.saturating_add(*n))
    }

    /// `forged 3, replayed 1`; empty when none.
    pub fn describe(&self) -> String {
        Refusal::ALL
            .iter()
            .zip(self.counts)
            .filter(|(_, n)| *n > 0)
            .map(|(r, n)| format!("{} {n}", r.name()))
            .collect::<Vec<_>>()
            .join(", ")
    }
}

/// Words of the window's bitmap: one more than [`WINDOW`] needs, so the word the top counter
/// moves into is never one the window still reads (RFC 6479).
const WORDS: u64 = WINDOW / 64 + 1;

/// The counters seen: the highest, and a bitmap of the [`WINDOW`] below it.
#[derive(Clone, Default)]
struct Window {
    top: Option<u64>,
    bits: [u64; WORDS as usize],
}

impl Window {
    fn bit(&self, c: u64) -> (usize, u64) {
        (((c / 64) % WORDS) as usize, 1 << (c % 64))
    }

    /// Whether counter `c` is new and inside the window.
    fn fresh(&self, c: u64) -> bool {
        match self.top {
            None => true,
            Some(t) if c > t => true,
            Some(t) if t - c >= WINDOW => false,
            Some(_) => {
                let (w, m) = self.bit(c);
                self.bits[w] & m == 0
            }
        }
    }

    /// Marks `c` seen (after it was authenticated).
    fn mark(&mut self, c: u64) {
        match self.top {
            Some(t) if c <= t => {}
            _ => {
                // Clear the words the window slides past.
                let from = self.top.map_or(0, |t| t / 64 + 1);
                let to = c / 64;
                let n = (to + 1).saturating_sub(from).min(WORDS);
                for i in 0..n {
                    let w = ((to - i) % WORDS) as usize;
                    self.bits[w] = 0;
                }
                self.top = Some(c);
            }
        }
        let (w, m) = self.bit(c);
        self.bits[w] |= m;
    }
}

/// Opens one direction of one channel: TCP strictly in order, UDP within the replay window.
pub struct Opener {
    aead: LessSafeKey,
    window: Window,
    strict: bool,
}

impl Opener {
    /// A datagram opener of `key` that has seen counters up to `top` (None: none yet): a socket
    /// handed on refuses what its last owner took.
    pub fn resume(key: &[u8; KEY_LEN], top: Option<u64>) -> Self {
        // Every counter up to `top` counts as seen, whether or not the last owner took it.
        let window = match top {
            Some(t) => Window {
                top: Some(t),
                bits: [u64::MAX; WORDS as usize],
            },
            None => Window::default(),
        };
        Self {
            aead: aead(key),
            window,
            strict: false,
        }
    }

    /// The highest counter taken (None: none yet).
    pub fn top(&self) -> Option<u64> {
        self.window.top
    }

    /// Checks `counter` (from `header`), verifies the tag at the end of `sealed` (ciphertext,
    /// then tag) and decrypts it in place: the plaintext's length, at the start of `sealed`.
    pub fn open(
        &mut self,
        header: &[u8],
        counter: u64,
        sealed: &mut [u8],
    ) -> Result<usize, Refusal> {
        if sealed.len() < TAG_LEN {
            return Err(Refusal::Malformed);
        }
        // Authenticated first, so a forgery is counted as one whatever counter it claims; a
        // genuine message whose counter is not new is a replay, and its bytes are never handed
        // on.
        let expected = self.window.top.map_or(0, |t| t + 1);
        let fresh = !(self.strict && counter != expected) && self.window.fresh(counter);
        let n = self
            .aead
            .open_in_place(nonce(counter), Aad::from(header), sealed)
            .map_err(|_| Refusal::Forged)?
            .len();
        if !fresh {
            return Err(Refusal::Replayed);
        }
        self.window.mark(counter);
        Ok(n)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_window_slides_and_forgets_nothing_inside_it() {
        let mut w = Window::default();
        for c in (0..5000).step_by(3) {
            assert!(w.fresh(c));
            w.mark(c);
            assert!(!w.fresh(c));
        }
        assert!(w.fresh(4999) && w.fresh(4997) && !w.fresh(4998 - 3 * 10) && !w.fresh(10));
        w.mark(1_000_000);
        assert!(w.fresh(999_999) && !w.fresh(1_000_000 - WINDOW));
    }
}
