//! An observer's ports on a run (`deltaloop top`, an external tool): subscribers on services
//! that already exist, never created here, through the spare slots the loop keeps
//! ([`crate::ipc::SPARE`]). Each requires the service's safe overflow, so an observer can never
//! make the loop's publishers wait; an error's `detail` is iceoryx2's (`DoesNotExist`,
//! `ExceedsMax…`).
//!
//! They are opened here, with concrete payloads, for the build: iceoryx2's `open` instantiates
//! the TOML reading of a service's static config, which each crate that calls it with a generic
//! payload would compile again (release builds share no generics between crates).

use crate::ipc::{IpcContext, IpcError, Svc, control_service, service_name};
use crate::wire::{ControlMsg, Sender, StateMsg, TelemetryMsg, TorqueMsg};
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;
use std::fmt::Debug;

/// An observer's subscriber on the existing service `what` of run `run_id`, `buffer` deep.
fn subscribe<T: ZeroCopySend + Debug + Copy + 'static>(
    node: &Node<Svc>,
    run_id: &str,
    what: &str,
    buffer: usize,
) -> Result<Subscriber<Svc, T, ()>, IpcError> {
    node.service_builder(&service_name(run_id, what)?)
        .publish_subscribe::<T>()
        .enable_safe_overflow(true)
        .open()
        .ipc(format!("open service {what}"))?
        .subscriber_builder()
        .buffer_size(buffer)
        .create()
        .ipc(format!("subscriber on {what}"))
}

/// An observer's subscriber on `state`, `buffer` deep.
pub fn state(
    node: &Node<Svc>,
    run_id: &str,
    buffer: usize,
) -> Result<Subscriber<Svc, StateMsg, ()>, IpcError> {
    subscribe(node, run_id, "state", buffer)
}

/// An observer's subscriber on `torque`, `buffer` deep.
pub fn torque(
    node: &Node<Svc>,
    run_id: &str,
    buffer: usize,
) -> Result<Subscriber<Svc, TorqueMsg, ()>, IpcError> {
    subscribe(node, run_id, "torque", buffer)
}

/// An observer's subscriber on `telemetry`, `buffer` deep.
pub fn telemetry(
    node: &Node<Svc>,
    run_id: &str,
    buffer: usize,
) -> Result<Subscriber<Svc, TelemetryMsg, ()>, IpcError> {
    subscribe(node, run_id, "telemetry", buffer)
}

/// An observer's subscriber on the control service `from` publishes on ([`control_service`]),
/// `buffer` deep.
pub fn control(
    node: &Node<Svc>,
    run_id: &str,
    from: Sender,
    buffer: usize,
) -> Result<Subscriber<Svc, ControlMsg, ()>, IpcError> {
    subscribe(node, run_id, control_service(from), buffer)
}
