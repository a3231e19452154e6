//! The controller side of deltaloop: the controller's tick ([`tick`]), which every loop mode
//! calls, and the controller process (`deltaloop-controller`, [`process`]), which runs that tick
//! over iceoryx2 with the joint reference in a fixed ring ([`ring`]). The laws themselves are
//! `deltaloop-law` (pure math). Model-free: this crate never depends on the plant.

pub mod process;
pub mod ring;
pub mod tick;

pub use tick::{ControllerSide, measurement, reference};
