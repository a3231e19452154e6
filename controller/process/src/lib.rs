//! The controller process (`deltaloop-controller`, [`process`]): the controller's tick, which
//! every loop mode calls (`deltaloop-controller-tick`, pure, re-exported as [`tick`]), served over
//! the loop's transport its binary picks (`deltaloop_transport::exchange`), with the joint reference in a fixed ring ([`ring`]). The laws themselves are
//! `deltaloop-law` (pure math). Model-free: this crate never depends on the plant.

pub mod process;
pub mod ring;
/// The controller's tick: `deltaloop-controller-tick`.
pub use deltaloop_controller_tick as tick;

pub use tick::{ControllerSide, measurement, reference};
