//! What a run's MCAP file (and `top`'s live view) receives every tick, encoded here rather than
//! in the supervisor: the robot's 3D scene ([`scene`]), its joint state ([`cdr`]), and the file
//! they go to ([`file::McapFile`], whose writer's generic code is instantiated here). The
//! supervisor is compiled for its build time (opt-level 0 in release); this crate is optimised,
//! so writing a tick's messages costs the recording supervisor tens of µs, not hundreds.

pub mod cdr;
pub mod file;
pub mod scene;
