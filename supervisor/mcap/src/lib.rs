//! The MCAP encoding of a robot in motion: its 3D scene ([`scene`], `foxglove.SceneUpdate`), its
//! joint state ([`cdr`], ROS 2 `JointState` in CDR), and the chunked, LZ4-compressed file they
//! go to ([`file::McapFile`]). Plain encoders over the model, with no run folder, no study and no
//! transport (tests/e2e/crate_graph.rs): the report writes a run's file and its live bus with
//! them, a tick's messages in tens of µs.

pub mod cdr;
pub mod file;
pub mod scene;
