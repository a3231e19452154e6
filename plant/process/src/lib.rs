//! The plant side of deltaloop: the plant's tick ([`tick`]), which every loop mode calls, and the
//! plant process (`deltaloop-plant`, [`process`]), which runs that tick over iceoryx2. The model
//! itself is `deltaloop-model` (pure math); this crate adds the loop and the transport.

pub mod process;
pub mod tick;

pub use tick::{Arrival, Physics, PlantSide, PlantStop, plant_from_config, sim_config};
