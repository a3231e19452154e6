//! The plant process (`deltaloop-plant`, [`process`]): the plant's tick, which every loop mode
//! calls (`deltaloop-plant-tick`, pure, re-exported as [`tick`]), served over iceoryx2 on one host
//! or the direct link across two. The model itself is `deltaloop-model`; this crate adds the loop
//! and the transport.

pub mod process;
/// The plant's tick: `deltaloop-plant-tick`.
pub use deltaloop_plant_tick as tick;

pub use tick::{Arrival, Physics, PlantSide, PlantStop, plant_from_config, sim_config};
