//! A run split over two hosts. On the supervisor's host `deltaloop run … --controller-remote
//! HOST:PORT` (or `--plant-remote HOST:PORT`) runs `deltaloop-bridge near` in place of the
//! controller (or the plant) process, so the supervisor's handshake, timeouts, fault
//! classification and clean-up apply to it as to any child; on the other host `deltaloop join
//! HOST:PORT --role controller` (or `--role plant`) runs `deltaloop-bridge far`, which starts
//! that process there. docs/guide/two-hosts.md.

use crate::loops::procs::exe_dir;
use anyhow::{Context, Result, bail};
use deltaloop_bridge::{EmuArgs, Role};
use deltaloop_config::{LoopMode, RunConfig};
use std::process::Command;

/// `--controller-remote`, `--plant-remote` and the emulated link, shared by `run` and `soak`.
#[derive(Clone, Debug, Default, clap::Args)]
pub struct RemoteArgs {
    /// Run the controller on another host: listen on HOST:PORT of this host (TCP and UDP) for
    /// `deltaloop join HOST:PORT --role controller` there. Lockstep or realtime.
    #[arg(long, value_name = "HOST:PORT")]
    pub controller_remote: Option<String>,
    /// Run the plant on another host: listen on HOST:PORT of this host (TCP and UDP) for
    /// `deltaloop join HOST:PORT --role plant` there. Lockstep or realtime.
    #[arg(long, value_name = "HOST:PORT")]
    pub plant_remote: Option<String>,
    #[command(flatten)]
    pub emu: EmuArgs,
}

impl RemoteArgs {
    /// The remote process's flag, its role and endpoint, if one is remote; one line naming the
    /// flags if both are.
    fn remote(&self) -> Result<Option<(&'static str, Role, &str)>> {
        match (&self.controller_remote, &self.plant_remote) {
            (Some(_), Some(_)) => bail!(
                "--plant-remote with --controller-remote: one process runs on another host, the other here with the supervisor (give one of the two)"
            ),
            (Some(ep), None) => Ok(Some(("--controller-remote", Role::Controller, ep))),
            (None, Some(ep)) => Ok(Some(("--plant-remote", Role::Plant, ep))),
            (None, None) => Ok(None),
        }
    }

    /// Puts the near bridge in the remote process's place; one line naming the flag otherwise.
    pub fn apply(&self, cfg: &mut RunConfig) -> Result<()> {
        let emu = self.emu.emulation()?;
        let Some((flag, role, ep)) = self.remote()? else {
            if !emu.is_off() {
                bail!(
                    "--link-delay-us, --link-jitter-us and --link-loss need --controller-remote or --plant-remote"
                );
            }
            return Ok(());
        };
        let addr =
            deltaloop_bridge::parse_endpoint(ep).map_err(|e| anyhow::anyhow!("{flag}: {e}"))?;
        let command = if role == Role::Plant {
            &mut cfg.plant.command
        } else {
            &mut cfg.controller.command
        };
        if !command.is_empty() {
            bail!(
                "{flag} and a {role} command (--{role}-cmd or {role}.command) exclude each other: give the command to `deltaloop join --role {role} --{role}-cmd` on the other host"
            );
        }
        let bridge = exe_dir()?.join("deltaloop-bridge");
        let e = &self.emu;
        *command = vec![
            bridge.display().to_string(),
            "near".into(),
            "--role".into(),
            role.name().into(),
            "--listen".into(),
            addr.to_string(),
            format!("--link-delay-us={}", e.link_delay_us),
            format!("--link-jitter-us={}", e.link_jitter_us),
            format!("--link-loss={}", e.link_loss),
            format!("--link-seed={}", e.link_seed),
            format!("--link-spin-us={}", e.link_spin_us),
        ];
        Ok(())
    }

    /// A remote process needs a process mode.
    pub fn check_mode(&self, mode: LoopMode) -> Result<()> {
        if let Some((flag, ..)) = self.remote()?
            && mode == LoopMode::Inproc
        {
            bail!("{flag} needs --mode lockstep or realtime (inproc has no processes)");
        }
        Ok(())
    }
}

/// `deltaloop join`: what to run on the other host.
pub struct Join<'a> {
    pub endpoint: &'a str,
    /// `controller` or `plant`.
    pub role: Role,
    pub controller_cmd: Option<&'a str>,
    pub plant_cmd: Option<&'a str>,
    pub runs: u32,
    pub wait_s: u64,
    pub spin_us: u32,
}

/// Replaces this process with `deltaloop-bridge far` (its exit code is the far process's);
/// returns only if that cannot start.
pub fn join(j: &Join<'_>) -> Result<()> {
    let addr = deltaloop_bridge::parse_endpoint(j.endpoint)
        .map_err(|e| anyhow::anyhow!("deltaloop join: {e}"))?;
    deltaloop_bridge::far::command(j.role, j.controller_cmd, j.plant_cmd)?;
    let bridge = exe_dir()?.join("deltaloop-bridge");
    let mut c = Command::new(&bridge);
    c.args([
        "far",
        "--role",
        j.role.name(),
        "--connect",
        &addr.to_string(),
    ])
    .arg(format!("--runs={}", j.runs))
    .arg(format!("--wait-s={}", j.wait_s))
    .arg(format!("--spin-us={}", j.spin_us));
    if let Some(cmd) = j.controller_cmd {
        c.arg(format!("--controller-cmd={cmd}"));
    }
    if let Some(cmd) = j.plant_cmd {
        c.arg(format!("--plant-cmd={cmd}"));
    }
    use std::os::unix::process::CommandExt;
    let e = c.exec();
    Err(e).with_context(|| {
        format!(
            "cannot start {} (build it: `cargo build --release` puts it next to deltaloop)",
            bridge.display()
        )
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cfg() -> RunConfig {
        RunConfig::from_file(std::path::Path::new(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../configs/s1-nominal.toml"
        )))
        .unwrap()
    }

    #[test]
    fn remote_flags_are_checked_with_one_line() {
        let remote = |ep: &str| RemoteArgs {
            controller_remote: Some(ep.into()),
            ..Default::default()
        };
        let mut c = cfg();
        remote("127.0.0.1:7447").apply(&mut c).unwrap();
        assert!(c.controller.command[0].ends_with("deltaloop-bridge"));
        assert!(c.controller.command.contains(&"127.0.0.1:7447".to_string()));
        let e = remote("127.0.0.1")
            .apply(&mut cfg())
            .unwrap_err()
            .to_string();
        assert!(
            e.starts_with("--controller-remote: endpoint `127.0.0.1`: no port"),
            "{e}"
        );
        let mut c = cfg();
        c.controller.command = vec!["my-controller".into()];
        let e = remote("127.0.0.1:7447")
            .apply(&mut c)
            .unwrap_err()
            .to_string();
        assert!(e.contains("exclude each other"), "{e}");
        let lossy = RemoteArgs {
            emu: EmuArgs {
                link_loss: 0.1,
                ..Default::default()
            },
            ..Default::default()
        };
        let e = lossy.apply(&mut cfg()).unwrap_err().to_string();
        assert!(
            e.contains("need --controller-remote or --plant-remote"),
            "{e}"
        );
        let e = remote("127.0.0.1:7447")
            .check_mode(LoopMode::Inproc)
            .unwrap_err()
            .to_string();
        assert!(e.contains("lockstep or realtime"), "{e}");
        assert!(!e.contains('\n'), "{e}");
    }

    #[test]
    fn plant_remote_flags_are_checked_with_one_line() {
        let remote = |ep: &str| RemoteArgs {
            plant_remote: Some(ep.into()),
            ..Default::default()
        };
        let mut c = cfg();
        remote("127.0.0.1:7447").apply(&mut c).unwrap();
        assert!(c.plant.command[0].ends_with("deltaloop-bridge"));
        assert!(c.plant.command.windows(2).any(|w| w == ["--role", "plant"]));
        assert!(c.plant.command.contains(&"127.0.0.1:7447".to_string()));
        assert!(c.controller.command.is_empty());
        let one_line = |e: anyhow::Error, says: &[&str]| {
            let e = e.to_string();
            assert!(
                says.iter().all(|s| e.contains(s)) && !e.contains('\n'),
                "{e}"
            );
        };
        one_line(
            remote("127.0.0.1").apply(&mut cfg()).unwrap_err(),
            &["--plant-remote: endpoint `127.0.0.1`: no port"],
        );
        let both = RemoteArgs {
            controller_remote: Some("127.0.0.1:7447".into()),
            ..remote("127.0.0.1:7448")
        };
        one_line(
            both.apply(&mut cfg()).unwrap_err(),
            &[
                "--plant-remote with --controller-remote",
                "give one of the two",
            ],
        );
        one_line(
            both.check_mode(LoopMode::Lockstep).unwrap_err(),
            &["--plant-remote with --controller-remote"],
        );
        let mut c = cfg();
        c.plant.command = vec!["my-plant".into()];
        one_line(
            remote("127.0.0.1:7447").apply(&mut c).unwrap_err(),
            &[
                "--plant-remote and a plant command",
                "--role plant --plant-cmd",
            ],
        );
        one_line(
            remote("127.0.0.1:7447")
                .check_mode(LoopMode::Inproc)
                .unwrap_err(),
            &["--plant-remote needs --mode lockstep or realtime"],
        );
        remote("127.0.0.1:7447")
            .check_mode(LoopMode::Realtime)
            .unwrap();
    }

    #[test]
    fn join_refuses_the_other_roles_command_with_one_line() {
        let j = |role, controller_cmd, plant_cmd| Join {
            endpoint: "127.0.0.1:7447",
            role,
            controller_cmd,
            plant_cmd,
            runs: 1,
            wait_s: 1,
            spin_us: 0,
        };
        for (role, c, p, says) in [
            (
                Role::Plant,
                Some("ctl"),
                None,
                "--controller-cmd with --role plant",
            ),
            (
                Role::Controller,
                None,
                Some("pl"),
                "--plant-cmd with --role controller",
            ),
            (Role::Plant, None, Some("  "), "--plant-cmd is empty"),
        ] {
            let e = join(&j(role, c, p)).unwrap_err().to_string();
            assert!(e.contains(says) && !e.contains('\n'), "{e}");
        }
    }
}
