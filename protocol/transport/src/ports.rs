//! The ports of a run's services, one concrete type per service and end: [`StateOut`] publishes
//! states, [`StateIn`] takes them, [`Wake`] and [`Ping`] are the two ends of a wake-up event, and
//! so on. Every process goes through these.
//!
//! Why not iceoryx2's own generic ports: a release build shares no generic code between crates,
//! so each crate that sent, received or dropped a `Publisher<_, StateMsg, _>` compiled iceoryx2's
//! code for it again (its connection set-up included): about a sixth of the workspace's own
//! build. Here it is compiled once, in this crate; the loop pays one call per send or receive.
//! Each type holds its port in a `ManuallyDrop` and drops it in a drop of its own, so even the
//! port's drop is compiled here and not in the crate that drops it.

use crate::iox::{IpcContext, IpcError, Svc, describe_process};
use crate::wire::{ControlMsg, RefSample, StateMsg, TelemetryMsg, TorqueMsg};
use iceoryx2::identifiers::UniquePublisherId;
use iceoryx2::port::listener::{Listener, ListenerWaitError};
use iceoryx2::port::notifier::{Notifier, NotifierNotifyError};
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::port::{ReceiveError, SendError};
use iceoryx2::prelude::*;
use iceoryx2::sample::Sample;
use iceoryx2::service::port_factory::PortFactory as _;
use iceoryx2::service::port_factory::publish_subscribe::PortFactory;
use std::mem::ManuallyDrop;
use std::time::Duration;

/// A message taken from a service with who published it.
#[derive(Clone, Copy, Debug)]
pub struct Sent<T> {
    pub msg: T,
    /// The publishing port.
    pub origin: UniquePublisherId,
    /// The publishing process's pid (0 when iceoryx2 cannot say).
    pub pid: u32,
}

/// A port that connects to its peers now (iceoryx2 connects lazily, on the first send or
/// receive: set-up work the loop's first tick should not do).
pub trait Connect {
    fn connect(&self) -> Result<(), IpcError>;
}

/// [`Connect`] for ports whose iceoryx2 port has `update_connections`.
macro_rules! connect {
    ($($ty:ident),*) => {$(
        impl Connect for $ty {
            fn connect(&self) -> Result<(), IpcError> {
                use iceoryx2::port::update_connections::UpdateConnections;
                self.0.update_connections().ipc("connect the loop's ports")
            }
        }
    )*};
}

/// Drops the port held in `ManuallyDrop` (here, so its drop is compiled in this crate).
macro_rules! drop_here {
    ($($ty:ident),*) => {$(
        impl Drop for $ty {
            fn drop(&mut self) {
                // SAFETY: the port is dropped once, here, and never used after.
                unsafe { ManuallyDrop::drop(&mut self.0) }
            }
        }
    )*};
}

/// A publisher slot refused on service `what` (`e`), naming the processes (`holders`, pids)
/// that hold its slots.
fn slot_taken(what: &str, e: &dyn std::fmt::Debug, holders: &[u32]) -> IpcError {
    let held = if holders.is_empty() {
        String::new()
    } else {
        let who: Vec<String> = holders.iter().map(|&p| describe_process(p)).collect();
        format!(
            ": its only publisher slot is held by another process ({})",
            who.join("; ")
        )
    };
    IpcError {
        what: format!("publisher on {what}"),
        detail: format!("{e:?}{held}"),
    }
}

/// The service of one fixed-size message type and its two ends.
macro_rules! message_ports {
    ($($msg:ty: $service:ident, $out:ident, $in:ident;)*) => {$(
        #[doc = concat!("A service of `", stringify!($msg), "`: makes its ports.")]
        pub struct $service(ManuallyDrop<PortFactory<Svc, $msg, ()>>);

        impl From<PortFactory<Svc, $msg, ()>> for $service {
            fn from(f: PortFactory<Svc, $msg, ()>) -> Self {
                Self(ManuallyDrop::new(f))
            }
        }

        impl $service {
            /// A publisher (one of the service's publisher slots).
            pub fn publisher(&self, what: &str) -> Result<$out, IpcError> {
                let p = self.0.publisher_builder().create().ipc(what)?;
                Ok($out(ManuallyDrop::new(p)))
            }

            /// The only publisher, or an error naming the process that holds the one slot
            /// (regression: a stranger that took the slot of `state` first had the run blame the
            /// plant, with nobody named).
            pub fn sole_publisher(&self, what: &str) -> Result<$out, IpcError> {
                let f = &self.0;
                let p = f.publisher_builder().create().map_err(|e| {
                    let mut holders = Vec::new();
                    f.dynamic_config().list_publishers(|p| {
                        holders.push(p.node_id.pid::<Svc>().map_or(0, |p| p.value() as u32));
                        CallbackProgression::Continue
                    });
                    slot_taken(what, &e, &holders)
                })?;
                Ok($out(ManuallyDrop::new(p)))
            }

            /// The service's settings (as created, or as found when opened).
            pub fn static_config(
                &self,
            ) -> &iceoryx2::service::static_config::publish_subscribe::StaticConfig {
                self.0.static_config()
            }

            /// A subscriber queueing `buffer` samples (None: the service's default).
            pub fn subscriber(&self, buffer: Option<usize>, what: &str) -> Result<$in, IpcError> {
                let b = self.0.subscriber_builder();
                let b = match buffer {
                    Some(n) => b.buffer_size(n),
                    None => b,
                };
                Ok($in(ManuallyDrop::new(b.create().ipc(what)?)))
            }
        }

        #[doc = concat!("Publishes `", stringify!($msg), "`.")]
        pub struct $out(ManuallyDrop<Publisher<Svc, $msg, ()>>);

        impl $out {
            /// Publishes a copy of `m`; the number of subscribers it reached.
            pub fn send_copy(&self, m: $msg) -> Result<usize, SendError> {
                self.0.send_copy(m)
            }
        }

        #[doc = concat!("Takes `", stringify!($msg), "` in order.")]
        pub struct $in(ManuallyDrop<Subscriber<Svc, $msg, ()>>);

        impl $in {
            /// The oldest message queued, if any.
            pub fn receive(&self) -> Result<Option<$msg>, ReceiveError> {
                Ok(self.0.receive()?.map(|s| *s.payload()))
            }

            /// [`receive`](Self::receive), with the port and process that published it.
            pub fn receive_sent(&self) -> Result<Option<Sent<$msg>>, ReceiveError> {
                Ok(self.0.receive()?.map(|s| Sent {
                    msg: *s.payload(),
                    origin: s.origin(),
                    pid: s.header().node_id().pid::<Svc>().map_or(0, |p| p.value() as u32),
                }))
            }

            /// Whether a message is queued.
            pub fn has_samples(&self) -> Result<bool, IpcError> {
                self.0.has_samples().ipc("has samples")
            }
        }

        drop_here!($service, $out, $in);
        connect!($out, $in);
    )*};
}

message_ports! {
    StateMsg: StateService, StateOut, StateIn;
    TorqueMsg: TorqueService, TorqueOut, TorqueIn;
    TelemetryMsg: TelemetryService, TelemetryOut, TelemetryIn;
    ControlMsg: ControlService, ControlOut, ControlIn;
}

/// A process's node in a run: the owner of its ports (see [`crate::ipc::node`]); derefs to
/// iceoryx2's node for the functions of [`crate::ipc`] that open services on it.
pub struct RunNode(ManuallyDrop<Node<Svc>>);

impl std::ops::Deref for RunNode {
    type Target = Node<Svc>;
    fn deref(&self) -> &Node<Svc> {
        &self.0
    }
}

/// The reference's publisher: chunks of rows.
pub struct RefOut(ManuallyDrop<Publisher<Svc, [RefSample], ()>>);

impl RefOut {
    /// Sends one chunk of `rows` rows, row `i` made by `row(i)`.
    pub fn send_chunk(
        &self,
        rows: usize,
        row: &mut dyn FnMut(usize) -> RefSample,
    ) -> Result<usize, IpcError> {
        let sample = self
            .0
            .loan_slice_uninit(rows)
            .ipc("loan a reference chunk")?;
        sample
            .write_from_fn(row)
            .send()
            .ipc("send a reference chunk")
    }
}

/// The reference's subscriber.
pub struct RefIn(ManuallyDrop<Subscriber<Svc, [RefSample], ()>>);

/// A borrowed chunk of the reference; returned to the publisher when dropped.
pub struct RefChunk(ManuallyDrop<Sample<Svc, [RefSample], ()>>);

impl RefIn {
    /// The oldest chunk queued, if any.
    pub fn receive(&self) -> Result<Option<RefChunk>, ReceiveError> {
        Ok(self.0.receive()?.map(|s| RefChunk(ManuallyDrop::new(s))))
    }
}

impl RefChunk {
    /// The chunk's rows.
    pub fn payload(&self) -> &[RefSample] {
        self.0.payload()
    }
}

/// The listening end of a wake-up event.
pub struct Wake(ManuallyDrop<Listener<Svc>>);

impl Wake {
    /// Takes every pending event, without waiting.
    pub fn try_wait(&self) -> Result<u64, ListenerWaitError> {
        self.0.try_wait(|_| {})
    }

    /// Waits up to `timeout` for an event (iceoryx2's own wait: rounded up to whole jiffies)
    /// and takes every pending one.
    pub fn timed_wait(&self, timeout: Duration) -> Result<u64, ListenerWaitError> {
        self.0.timed_wait(|_| {}, timeout)
    }

    /// The descriptor to poll for a pending event (this port's; valid while it lives).
    pub fn fd(&self) -> i32 {
        use iceoryx2::prelude::FileDescriptorBased;
        // SAFETY: the descriptor stays owned by the listener; the caller only polls it.
        unsafe { self.0.file_descriptor().native_handle() }
    }
}

/// The notifying end of a wake-up event.
pub struct Ping(ManuallyDrop<Notifier<Svc>>);

impl Ping {
    /// Wakes the listeners; how many there were.
    pub fn notify(&self) -> Result<usize, NotifierNotifyError> {
        self.0.notify()
    }
}

/// Wraps the port made in [`crate::ipc`].
macro_rules! from_port {
    ($($ty:ident: $port:ty),*) => {$(
        impl From<$port> for $ty {
            fn from(p: $port) -> Self {
                Self(ManuallyDrop::new(p))
            }
        }
    )*};
}

from_port!(
    RunNode: Node<Svc>,
    RefOut: Publisher<Svc, [RefSample], ()>,
    RefIn: Subscriber<Svc, [RefSample], ()>,
    Wake: Listener<Svc>,
    Ping: Notifier<Svc>
);
drop_here!(RunNode, RefOut, RefIn, RefChunk, Wake, Ping);
connect!(Ping);
