//! How a loop process that may run across two hosts gets its transport ([`Handoff`], the
//! [`Connector`] its binary supplies): at set-up it says HELLO to the bridge beside it, if the run
//! has a link and a bridge started it; at START the bridge's answer picks the transport. This
//! `match` is the one place a transport is picked.

use crate::direct;
use crate::transport::{Direct, LinkError};
use deltaloop_config::RunConfig;
use deltaloop_transport::exchange::{Connector, Iceoryx, OverTransport};
use deltaloop_transport::handoff;

/// The hand-off with the bridge beside the process (None: no link, or no bridge: iceoryx2).
#[derive(Debug, Default)]
pub struct Handoff {
    end: Option<handoff::End>,
}

impl Connector for Handoff {
    type Error = LinkError;

    fn prepare(&mut self, cfg: &RunConfig) -> Result<(), LinkError> {
        if cfg.link.is_some() {
            self.end = direct::hello()?;
        }
        Ok(())
    }

    /// The link's socket if the bridge handed it on, else iceoryx2 (on one host, or relayed by
    /// the bridge).
    fn connect<V: OverTransport>(&mut self, then: V) -> Result<V::Output, LinkError> {
        let Some(end) = &self.end else {
            return Ok(then.run(Iceoryx));
        };
        Ok(match direct::answer(end)? {
            Some(udp) => then.run(Direct::new(udp, end)),
            None => then.run(Iceoryx),
        })
    }
}
