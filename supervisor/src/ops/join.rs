//! A run split over two hosts. On the plant's host `deltaloop run … --controller-remote HOST:PORT`
//! runs `deltaloop-bridge near` in place of the controller process (so the supervisor's
//! handshake, timeouts, fault classification and clean-up apply to it as to any controller); on
//! the other host `deltaloop join HOST:PORT --role controller` runs `deltaloop-bridge far`, which
//! starts the controller there. docs/guide/two-hosts.md.

use crate::loops::procs::exe_dir;
use anyhow::{Context, Result, bail};
use deltaloop_bridge::EmuArgs;
use deltaloop_config::{LoopMode, RunConfig};
use std::process::Command;

/// `--controller-remote` and the emulated link, shared by `run` and `soak`.
#[derive(Clone, Debug, Default, clap::Args)]
pub struct RemoteArgs {
    /// Run the controller on another host: listen on HOST:PORT of this host (TCP and UDP) for
    /// `deltaloop join HOST:PORT --role controller` there. Lockstep or realtime.
    #[arg(long, value_name = "HOST:PORT")]
    pub controller_remote: Option<String>,
    #[command(flatten)]
    pub emu: EmuArgs,
}

impl RemoteArgs {
    /// Puts the near bridge in the controller's place; one line naming the flag otherwise.
    pub fn apply(&self, cfg: &mut RunConfig) -> Result<()> {
        let emu = self.emu.emulation()?;
        let Some(ep) = &self.controller_remote else {
            if !emu.is_off() {
                bail!("--link-delay-us, --link-jitter-us and --link-loss need --controller-remote");
            }
            return Ok(());
        };
        let addr = deltaloop_bridge::parse_endpoint(ep)
            .map_err(|e| anyhow::anyhow!("--controller-remote: {e}"))?;
        if !cfg.controller.command.is_empty() {
            bail!(
                "--controller-remote and a controller command (--controller-cmd or controller.command) exclude each other: give the command to `deltaloop join --controller-cmd` on the other host"
            );
        }
        let bridge = exe_dir()?.join("deltaloop-bridge");
        let e = &self.emu;
        cfg.controller.command = vec![
            bridge.display().to_string(),
            "near".into(),
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

    /// A remote controller needs a process mode.
    pub fn check_mode(&self, mode: LoopMode) -> Result<()> {
        if self.controller_remote.is_some() && mode == LoopMode::Inproc {
            bail!(
                "--controller-remote needs --mode lockstep or realtime (inproc has no processes)"
            );
        }
        Ok(())
    }
}

/// `deltaloop join`: what to run on the controller's host.
pub struct Join<'a> {
    pub endpoint: &'a str,
    pub controller_cmd: Option<&'a str>,
    pub runs: u32,
    pub wait_s: u64,
    pub spin_us: u32,
}

/// Replaces this process with `deltaloop-bridge far` (its exit code is the far controller's);
/// returns only if that cannot start.
pub fn join(j: &Join<'_>) -> Result<()> {
    let addr = deltaloop_bridge::parse_endpoint(j.endpoint)
        .map_err(|e| anyhow::anyhow!("deltaloop join: {e}"))?;
    if j.controller_cmd
        .is_some_and(|c| c.split_whitespace().next().is_none())
    {
        bail!("--controller-cmd is empty: give a program and its arguments");
    }
    let bridge = exe_dir()?.join("deltaloop-bridge");
    let mut c = Command::new(&bridge);
    c.args([
        "far",
        "--role",
        "controller",
        "--connect",
        &addr.to_string(),
    ])
    .arg(format!("--runs={}", j.runs))
    .arg(format!("--wait-s={}", j.wait_s));
    if let Some(cmd) = j.controller_cmd {
        c.arg(format!("--controller-cmd={cmd}"));
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
        assert!(e.contains("need --controller-remote"), "{e}");
        let e = remote("127.0.0.1:7447")
            .check_mode(LoopMode::Inproc)
            .unwrap_err()
            .to_string();
        assert!(e.contains("lockstep or realtime"), "{e}");
        assert!(!e.contains('\n'), "{e}");
    }
}
