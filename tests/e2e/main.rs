//! deltaloop's end-to-end tests: one binary (one link of the whole supervisor), one module per
//! feature, and the support they share (`common`). Run one feature with
//! `cargo test --test e2e <module>::`, e.g. `cargo test --test e2e bridge_netns::`.

mod common;

mod bridge_netns;
mod c_abi;
mod ci_gate;
mod cli_run;
mod compensation;
mod crate_graph;
mod custom_process;
mod delay_injection;
mod doc_paths;
mod explain;
mod export_config;
mod export_mcap;
mod faults;
mod file_length;
mod foreign_peers;
mod input_hardening;
mod link_loopback;
mod live_monitor;
mod messages_monitors;
mod mujoco_plant;
mod observe;
mod out_claims;
mod paper;
mod process_modes;
mod python_interop;
mod realtime;
mod replay;
mod replay_merge_hardening;
mod ros2;
mod ros2_face;
mod ros2_live;
mod run_folder;
mod sensitivity;
mod soak;
mod sweep_cluster;
mod sweep_repeats;
mod timing_files;
mod top_foxglove;
mod whatif;
mod whatif_hardening;
mod wire_contract;
