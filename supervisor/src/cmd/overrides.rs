//! The flags `run` and `soak` share: overrides of the scenario file and the remote process, as
//! clap reads them; [`crate::ops`] takes them as plain [`Overrides`] and [`RemoteArgs`].

use super::words::Words;
use crate::ops::join::RemoteArgs;
use crate::ops::run::Overrides;
use deltaloop_config::{Compensation, DelaySource, Law, LinkEmulation, LinkPath, Overrun};
use std::path::PathBuf;

/// `--law`, `--seed`, `--plant-cmd`, … : overrides of a scenario file (None: keep the file's value).
#[derive(Clone, Debug, Default, clap::Args)]
pub struct OverrideArgs {
    /// Run only this law (repeatable).
    #[arg(long = "law", value_parser = Words::<Law>::new())]
    pub laws: Vec<Law>,
    /// TDE delay ℓ in ticks (controller.tde_delay_samples).
    #[arg(long)]
    pub tde_delay: Option<u32>,
    /// Transport delay d in ticks (plant.transport_delay_samples).
    #[arg(long)]
    pub transport_delay: Option<u32>,
    /// Transport delay beyond whole ticks, µs (plant.transport_delay_us; adds to --transport-delay).
    #[arg(long)]
    pub transport_delay_us: Option<f64>,
    /// Extra controller compute time per tick, µs (controller.compute_delay_us; realtime).
    #[arg(long)]
    pub compute_delay_us: Option<u32>,
    /// Delay compensation: `none`, or `predict` (the law acts on the state predicted for when
    /// its torque acts; controller.compensate, docs/controllers.md).
    #[arg(long, value_parser = Words::<Compensation>::new())]
    pub compensate: Option<Compensation>,
    /// The delay D₀ a compensated law assumes, µs (controller.compensate_delay_us; default: the
    /// transport delay).
    #[arg(long)]
    pub compensate_delay_us: Option<f64>,
    /// Where a compensated law's delay comes from: `config` (D₀) or `measured` each tick from the
    /// drives' reports, D₀ to D₀ + Ts (controller.compensate_delay; for realtime).
    #[arg(long, value_parser = Words::<DelaySource>::new())]
    pub compensate_delay: Option<DelaySource>,
    /// Sensor noise seed (sensor.seed).
    #[arg(long)]
    pub seed: Option<u64>,
    /// Realtime: what the plant does when its own process wakes later than
    /// loop.overrun_after_us (default one tick): stretch (pause simulated time for the stall),
    /// catch-up (run the backlog on the wall clock) or fault (stop the run) (loop.overrun).
    #[arg(long, value_parser = Overrun::parse)]
    pub overrun: Option<Overrun>,
    /// Hold at the end point after the motion, s (scenario.hold_s, 0..=86400).
    #[arg(long)]
    pub hold_s: Option<f64>,
    /// Run this command in place of the built-in plant process (plant.command; split at
    /// whitespace: put arguments with spaces in the scenario file's array).
    #[arg(long, value_name = "CMD")]
    pub plant_cmd: Option<String>,
    /// Run this command in place of the built-in controller process (controller.command).
    #[arg(long, value_name = "CMD")]
    pub controller_cmd: Option<String>,
    /// Which controller answers: `builtin` (the law, the default) or `ros2` (a ROS 2 node over
    /// DDS, on /robot_joint_states → /robot_joint_commands; docs/guide/ros2.md).
    #[arg(long, value_parser = Words::<ControllerKind>::new())]
    pub controller: Option<ControllerKind>,
    /// Publish the run live to ROS 2 (DDS, this host only unless [ros2] or ROS 2's environment
    /// say otherwise): /deltaloop/<law>/joint_states, /tf, /clock, /diagnostics, /rosout.
    #[arg(long)]
    pub ros2: bool,
    /// What the tables, summary.json and report.md call the controller that ran, beside the law
    /// it answered as (controller.label; default: --controller-cmd's program or script name).
    #[arg(long, value_name = "LABEL")]
    pub controller_label: Option<String>,
    /// Realtime: record the kernel's scheduling on the loop's CPUs and name the cause of each
    /// missed or late tick: `<law>.misses.csv`, `<law>.worst-miss.svg`, `miss_causes` in
    /// summary.json (record.explain; root; docs/guide/misses.md).
    #[arg(long)]
    pub explain: bool,
    #[command(flatten)]
    pub remote: RemoteFlags,
}

deltaloop_names::text_enum! {
    "lowercase", "controller";
    /// `--controller`: what answers the plant's states.
    pub enum ControllerKind {
        /// The built-in controller process (the law).
        Builtin,
        /// A ROS 2 node over DDS.
        Ros2,
    }
}

/// `--controller-remote`, `--plant-remote` and the emulated link, shared by `run` and `soak`.
#[derive(Clone, Debug, Default, clap::Args)]
pub struct RemoteFlags {
    /// Run the controller on another host: listen on HOST:PORT of this host (TCP and UDP) for
    /// `deltaloop join HOST:PORT --role controller` there. Lockstep or realtime.
    #[arg(long, value_name = "HOST:PORT")]
    pub controller_remote: Option<String>,
    /// Run the plant on another host: listen on HOST:PORT of this host (TCP and UDP) for
    /// `deltaloop join HOST:PORT --role plant` there. Lockstep or realtime.
    #[arg(long, value_name = "HOST:PORT")]
    pub plant_remote: Option<String>,
    /// The link's key file (`deltaloop link-key FILE` makes one; the other host's `join` needs a
    /// copy). Without it a one-time key is made and the `join` command that carries it printed.
    #[arg(long, value_name = "FILE")]
    pub link_key: Option<PathBuf>,
    /// Emulated one-way link delay, µs (each direction; the round trip grows by twice this).
    #[arg(long, default_value_t = 0.0)]
    pub link_delay_us: f64,
    /// Emulated one-way jitter, µs: uniform in [0, this] on top of the delay.
    #[arg(long, default_value_t = 0.0)]
    pub link_jitter_us: f64,
    /// Emulated loss: the fraction of datagrams dropped, 0..=1.
    #[arg(long, default_value_t = 0.0)]
    pub link_loss: f64,
    /// Seed of the emulated jitter and loss.
    #[arg(long, default_value_t = 1)]
    pub link_seed: u64,
    /// The near bridge polls this long for the reply after sending a state before it blocks, µs
    /// (0: it blocks at once; at most loop.torque_budget_us in realtime).
    #[arg(long, default_value_t = 0)]
    pub link_spin_us: u32,
    /// How the loop's messages cross: `direct` (plant and controller socket to socket; the
    /// default) or `relay` (through both bridges).
    #[arg(long, value_parser = Words::<LinkPath>::new())]
    pub link_path: Option<LinkPath>,
}

impl From<OverrideArgs> for Overrides {
    fn from(a: OverrideArgs) -> Self {
        Self {
            laws: a.laws,
            tde_delay: a.tde_delay,
            transport_delay: a.transport_delay,
            transport_delay_us: a.transport_delay_us,
            compute_delay_us: a.compute_delay_us,
            compensate: a.compensate,
            compensate_delay_us: a.compensate_delay_us,
            compensate_delay: a.compensate_delay,
            seed: a.seed,
            overrun: a.overrun,
            hold_s: a.hold_s,
            plant_cmd: a.plant_cmd,
            controller_cmd: a.controller_cmd,
            controller_label: a.controller_label,
            ros2_controller: a.controller == Some(ControllerKind::Ros2),
            ros2: a.ros2,
            explain: a.explain,
            remote: a.remote.into(),
        }
    }
}

impl From<RemoteFlags> for RemoteArgs {
    fn from(a: RemoteFlags) -> Self {
        Self {
            controller_remote: a.controller_remote,
            plant_remote: a.plant_remote,
            link_key: a.link_key,
            emulation: LinkEmulation {
                delay_us: a.link_delay_us,
                jitter_us: a.link_jitter_us,
                loss: a.link_loss,
                seed: a.link_seed,
            },
            spin_us: a.link_spin_us,
            path: a.link_path,
            quiet: false,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::builder::TypedValueParser;

    /// Every law is in `--law`'s help and parses by its name; another name is refused, naming
    /// the allowed ones.
    #[test]
    fn law_flag_offers_every_law_and_refuses_others() {
        let names: Vec<String> = Words::<Law>::new()
            .possible_values()
            .unwrap()
            .map(|v| v.get_name().to_string())
            .collect();
        assert_eq!(names, Law::ALL.iter().map(|l| l.name()).collect::<Vec<_>>());
        let cmd = clap::Command::new("t");
        for l in Law::ALL {
            assert_eq!(
                Words::<Law>::new()
                    .parse_ref(&cmd, None, l.name().as_ref())
                    .unwrap(),
                *l
            );
        }
        let e = Words::<Law>::new()
            .parse_ref(&cmd, None, "nope".as_ref())
            .unwrap_err();
        assert!(e.to_string().contains("allowed: tdc"), "{e}");
    }
}
