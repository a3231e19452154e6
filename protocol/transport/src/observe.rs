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
use crate::ports::{
    ControlIn, ControlService, StateIn, StateService, TelemetryIn, TelemetryService, TorqueIn,
    TorqueService,
};
use crate::wire::{ControlMsg, Sender, StateMsg, TelemetryMsg, TorqueMsg};
use iceoryx2::prelude::*;
use iceoryx2::service::port_factory::publish_subscribe::PortFactory;
use std::fmt::Debug;

/// An observer's subscriber on the existing service `what` of run `run_id`, `buffer` deep.
fn subscribe<T: ZeroCopySend + Debug + Copy + 'static, S: From<PortFactory<Svc, T, ()>>>(
    node: &Node<Svc>,
    run_id: &str,
    what: &str,
) -> Result<S, IpcError> {
    node.service_builder(&service_name(run_id, what)?)
        .publish_subscribe::<T>()
        .enable_safe_overflow(true)
        .open()
        .ipc(format!("open service {what}"))
        .map(Into::into)
}

/// An observer's subscriber on `state`, `buffer` deep.
pub fn state(node: &Node<Svc>, run_id: &str, buffer: usize) -> Result<StateIn, IpcError> {
    subscribe::<StateMsg, StateService>(node, run_id, "state")?
        .subscriber(Some(buffer), "subscriber on state")
}

/// An observer's subscriber on `torque`, `buffer` deep.
pub fn torque(node: &Node<Svc>, run_id: &str, buffer: usize) -> Result<TorqueIn, IpcError> {
    subscribe::<TorqueMsg, TorqueService>(node, run_id, "torque")?
        .subscriber(Some(buffer), "subscriber on torque")
}

/// An observer's subscriber on `telemetry`, `buffer` deep.
pub fn telemetry(node: &Node<Svc>, run_id: &str, buffer: usize) -> Result<TelemetryIn, IpcError> {
    subscribe::<TelemetryMsg, TelemetryService>(node, run_id, "telemetry")?
        .subscriber(Some(buffer), "subscriber on telemetry")
}

/// An observer's subscriber on the control service `from` publishes on ([`control_service`]),
/// `buffer` deep.
pub fn control(
    node: &Node<Svc>,
    run_id: &str,
    from: Sender,
    buffer: usize,
) -> Result<ControlIn, IpcError> {
    let what = control_service(from);
    subscribe::<ControlMsg, ControlService>(node, run_id, what)?
        .subscriber(Some(buffer), &format!("subscriber on {what}"))
}
