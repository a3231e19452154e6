//! The live side of `deltaloop top --foxglove`: the channels of a run's MCAP file, served over
//! Foxglove's WebSocket protocol by the `foxglove` crate (cargo feature `foxglove`).
//!
//! The protocol has no authentication, so the server listens on a loopback address only
//! ([`Server::start`] refuses any other); a viewer on another machine reaches it through an
//! authenticated tunnel (`ssh -L 8765:127.0.0.1:8765 host`).

use super::Bus;
use anyhow::{Context as _, Result, bail};
use foxglove::{ChannelBuilder, PartialMetadata, RawChannel, Schema, WebSocketServer};
use std::collections::BTreeMap;
use std::net::SocketAddr;
use std::sync::Arc;

/// A Foxglove WebSocket server on loopback, and the channels it serves.
pub struct Server {
    handle: Option<foxglove::WebSocketServerHandle>,
    ip: std::net::IpAddr,
    ctx: Arc<foxglove::Context>,
    schemas: Vec<Schema>,
    by_name: BTreeMap<&'static str, u16>,
    channels: Vec<Arc<RawChannel>>,
}

impl Server {
    /// Listens on `addr` (loopback only; port 0: any free port). Messages are stamped on the
    /// run's simulated clock (t = k·Ts, ns), as in the file.
    pub fn start(addr: SocketAddr) -> Result<Self> {
        if !addr.ip().is_loopback() {
            bail!(
                "--foxglove {addr}: not a loopback address; Foxglove's WebSocket protocol has no authentication, so deltaloop serves it on 127.0.0.1 or [::1] only (from another machine: ssh -L {port}:127.0.0.1:{port} this-host)",
                port = addr.port()
            );
        }
        let ctx = foxglove::Context::new();
        let handle = WebSocketServer::new()
            .name("deltaloop")
            .bind(addr.ip().to_string(), addr.port())
            .context(&ctx)
            .start_blocking()
            .with_context(|| format!("--foxglove {addr}: cannot listen"))?;
        Ok(Self {
            handle: Some(handle),
            ip: addr.ip(),
            ctx,
            schemas: Vec::new(),
            by_name: BTreeMap::new(),
            channels: Vec::new(),
        })
    }

    /// The address the server listens on (its port chosen if 0 was asked).
    pub fn addr(&self) -> SocketAddr {
        SocketAddr::new(self.ip, self.handle.as_ref().map_or(0, |h| h.port()))
    }

    /// Clients connected now.
    pub fn clients(&self) -> usize {
        self.handle.as_ref().map_or(0, |h| h.client_count())
    }
}

impl Bus for Server {
    fn active(&self) -> bool {
        self.clients() > 0
    }

    fn schema(&mut self, name: &'static str, encoding: &str, data: &str) -> Result<u16> {
        if let Some(&id) = self.by_name.get(name) {
            return Ok(id);
        }
        let id = u16::try_from(self.schemas.len())?;
        self.schemas
            .push(Schema::new(name, encoding, data.as_bytes().to_vec()));
        self.by_name.insert(name, id);
        Ok(id)
    }

    fn channel(&mut self, schema: u16, topic: &str, encoding: &str) -> Result<u16> {
        let schema = self
            .schemas
            .get(usize::from(schema))
            .cloned()
            .context("no such schema")?;
        let ch = ChannelBuilder::new(topic)
            .message_encoding(encoding)
            .schema(schema)
            .context(&self.ctx)
            .build_raw()
            .with_context(|| format!("channel {topic}"))?;
        self.channels.push(ch);
        Ok(u16::try_from(self.channels.len() - 1)?)
    }

    fn write(&mut self, channel: u16, t_ns: u64, data: &[u8]) -> Result<()> {
        let ch = self
            .channels
            .get(usize::from(channel))
            .context("no such channel")?;
        if ch.has_sinks() {
            ch.log_with_meta(data, PartialMetadata::with_log_time(t_ns));
        }
        Ok(())
    }
}

impl Drop for Server {
    fn drop(&mut self) {
        if let Some(h) = self.handle.take() {
            h.stop().wait_blocking();
        }
    }
}
