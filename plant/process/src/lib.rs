//! The plant process (`deltaloop-plant`, [`process`]): the plant's tick, which every loop mode
//! calls (`deltaloop-plant-tick`, pure, re-exported as [`tick`]), served over the loop's transport
//! (`deltaloop_transport::exchange`) its binary picks: iceoryx2 on one host, the link across two. The model itself is `deltaloop-model`; this crate adds the loop
//! and the transport.

pub mod process;
mod reply;
/// The plant's tick: `deltaloop-plant-tick`.
pub use deltaloop_plant_tick as tick;

pub use tick::{Arrival, Physics, PlantSide, PlantStop, plant_from_config, sim_config};
