//! deltaloop-link: the loop's datagrams between two hosts, sealed, as both ends send and take
//! them — the bridges on the relay path, and the plant and controller processes themselves on
//! the direct path ([`direct`]; as a transport of the loop, [`transport`], picked at START by
//! [`Handoff`], the connector the loop processes' binaries supply). The wire format ([`frame`]: a 24-byte header, the `#[repr(C)]`
//! wire types byte for byte, a 16-byte tag), the session keys and their sealing ([`seal`]), the
//! replies with their copies ([`replies`]), the socket with its emulated network ([`udp`],
//! [`emulation`]) and the clock offset between the hosts ([`offset`]). The handshake that makes a
//! session, the control connection and the program are the bridge's (`deltaloop-bridge`).
//!
//! Nothing here allocates after set-up; the only syscalls are the socket's and the clock.

pub mod bytes;
pub mod connect;
pub mod direct;
pub mod emulation;
pub mod frame;
pub mod offset;
pub mod replies;
pub mod seal;
pub mod transport;
pub mod udp;

pub use connect::Handoff;
