//! How the deltaloop processes talk: the wire types ([`wire`], `deltaloop-wire`), the iceoryx2 services of a run
//! ([`ipc`]) and an observer's ports on them ([`observe`]), the loop's own exchange behind one
//! interface ([`exchange`]: the traits, and iceoryx2 as one transport), the real-time helpers both loop
//! processes use ([`rt`]), their exit codes
//! ([`exit`]) and, with the cargo feature `args`, their command line (`args`). The config schema lives
//! apart, in `deltaloop-config`; this crate knows nothing of scenarios or physics.

#[cfg(feature = "args")]
pub mod args;
pub mod exchange;
pub mod exit;
pub mod handoff;
mod iox;
pub mod ipc;
pub mod observe;
pub mod ports;
pub mod rt;
/// The wire types, with iceoryx2's `ZeroCopySend`: `deltaloop-wire`.
pub use deltaloop_wire as wire;
