//! Where a link's near side listens and its far side connects: `HOST:PORT`.

use std::net::{SocketAddr, ToSocketAddrs};

/// `HOST:PORT` (an IPv4 or IPv6 address or a host name, and a port 1..=65535) → its first address.
pub fn parse_endpoint(s: &str) -> Result<SocketAddr, String> {
    let shown: String = deltaloop_wire::escape_peer_text(s)
        .chars()
        .take(100)
        .collect();
    let bad =
        |why: &str| format!("endpoint `{shown}`: {why} (expected HOST:PORT, e.g. 10.0.0.1:7447)");
    let (host, port) = s.rsplit_once(':').ok_or_else(|| bad("no port"))?;
    let port: u16 = port.parse().map_err(|_| bad("the port is not 1..=65535"))?;
    if port == 0 {
        return Err(bad("the port is not 1..=65535"));
    }
    if host.is_empty() {
        return Err(bad("no host"));
    }
    let host = host.trim_start_matches('[').trim_end_matches(']');
    (host, port)
        .to_socket_addrs()
        .map_err(|e| bad(&format!("cannot resolve the host: {e}")))?
        .next()
        .ok_or_else(|| bad("the host has no address"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn endpoints_are_checked_with_one_line() {
        assert_eq!(
            parse_endpoint("127.0.0.1:7447").unwrap(),
            "127.0.0.1:7447".parse().unwrap()
        );
        assert!(parse_endpoint("[::1]:7447").is_ok());
        for (bad, says) in [
            ("10.0.0.1", "no port"),
            ("10.0.0.1:0", "1..=65535"),
            ("10.0.0.1:70000", "1..=65535"),
            (":7447", "no host"),
            ("no.such.host.invalid:7447", "cannot resolve"),
        ] {
            let e = parse_endpoint(bad).unwrap_err();
            assert!(
                e.contains(says) && e.contains("HOST:PORT") && !e.contains('\n'),
                "{e}"
            );
        }
    }
}
