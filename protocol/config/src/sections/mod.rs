//! The sections of a scenario file, one module each: the serde struct, its defaults (from
//! [`crate::keys`]) and its `validate`, which checks each key against its declaration.

mod controller;
mod faults;
mod link;
mod plant;
mod record;
mod ros2;
mod run_loop;
mod scenario;
mod sensor;

pub use controller::ControllerSection;
pub use faults::{FaultInjection, FaultSection, TorqueLimit};
pub use link::{EmulationOutOfRange, LinkEmulation, LinkPath, LinkSection, RemoteSide};
pub use plant::{ApplyTorque, PlantSection};
pub use record::RecordSection;
pub use ros2::{Ros2Distro, Ros2Range, Ros2Section};
pub use run_loop::{LoopSection, Overrun};
pub use scenario::{PathKind, ScenarioSection, Segment};
pub use sensor::SensorSection;
