//! A run split over two hosts. On the supervisor's host `deltaloop run … --controller-remote
//! HOST:PORT` (or `--plant-remote HOST:PORT`) runs `deltaloop-bridge near` in place of the
//! controller (or the plant) process, so the supervisor's handshake, timeouts, fault
//! classification and clean-up apply to it as to any child; on the other host `deltaloop join
//! HOST:PORT --role controller` (or `--role plant`) runs `deltaloop-bridge far`, which starts
//! that process there. docs/guide/two-hosts.md.

use crate::link_key::{install_link_key, one_time_link_key};
use crate::procs::exe_dir;
use anyhow::{Context, Result, bail};
use deltaloop_config::{LinkEmulation, LinkPath, LinkSection, LoopMode, RemoteSide, RunConfig};
use deltaloop_link_setup::{KEY_ENV, LinkKey, far_command, parse_endpoint};
use std::path::{Path, PathBuf};
use std::process::Command;

/// Which process runs on another host, where the supervisor listens for it, and the emulated
/// link: `run`'s and `soak`'s `--controller-remote`, `--plant-remote`, `--link-*`.
#[derive(Clone, Debug, Default)]
pub struct RemoteArgs {
    /// Run the controller on another host: listen on HOST:PORT of this host (TCP and UDP) for
    /// `deltaloop join HOST:PORT --role controller` there. Lockstep or realtime.
    pub controller_remote: Option<String>,
    /// Run the plant on another host: listen on HOST:PORT of this host (TCP and UDP) for
    /// `deltaloop join HOST:PORT --role plant` there. Lockstep or realtime.
    pub plant_remote: Option<String>,
    /// The link's key file (`deltaloop link-key FILE` makes one; the other host's `join` needs a
    /// copy). Without it a one-time key is made and the `join` command that carries it printed.
    pub link_key: Option<PathBuf>,
    /// The emulated network (`--link-delay-us`, `--link-jitter-us`, `--link-loss`,
    /// `--link-seed`).
    pub emulation: LinkEmulation,
    /// How long the near bridge polls for a reply before it blocks, µs (`--link-spin-us`).
    pub spin_us: u32,
    /// How the loop's messages cross (`--link-path`; None: the config's, else direct).
    pub path: Option<LinkPath>,
    /// Say nothing of how to join (a sweep's loopback joins by itself).
    pub quiet: bool,
}

impl RemoteArgs {
    /// The remote process's flag, its role and endpoint, if one is remote; one line naming the
    /// flags if both are.
    fn remote(&self) -> Result<Option<(&'static str, RemoteSide, &str)>> {
        match (&self.controller_remote, &self.plant_remote) {
            (Some(_), Some(_)) => bail!(
                "--plant-remote with --controller-remote: one process runs on another host, the other here with the supervisor (give one of the two)"
            ),
            (Some(ep), None) => Ok(Some(("--controller-remote", RemoteSide::Controller, ep))),
            (None, Some(ep)) => Ok(Some(("--plant-remote", RemoteSide::Plant, ep))),
            (None, None) => Ok(None),
        }
    }

    /// Puts the near bridge in the remote process's place and the link in the config's
    /// `[link]`, from the flags or, without them, from a `[link]` the config already has (a run
    /// folder's config run again); one line naming the flag or key otherwise.
    pub fn apply(&self, cfg: &mut RunConfig) -> Result<()> {
        let emu = self.emulation;
        emu.check().map_err(|e| anyhow::anyhow!("{e}"))?;
        let link = match (self.remote()?, &cfg.link) {
            (Some((flag, role, ep)), _) => {
                let addr = parse_endpoint(ep).map_err(|e| anyhow::anyhow!("{flag}: {e}"))?;
                LinkSection {
                    remote: role,
                    listen: addr.to_string(),
                    delay_us: emu.delay_us,
                    jitter_us: emu.jitter_us,
                    loss: emu.loss,
                    seed: emu.seed,
                    spin_us: self.spin_us,
                    path: self.path.unwrap_or_default(),
                }
            }
            (None, Some(link)) if emu.is_off() => LinkSection {
                path: self.path.unwrap_or(link.path),
                ..link.clone()
            },
            (None, _) => {
                if !emu.is_off() {
                    bail!(
                        "--link-delay-us, --link-jitter-us and --link-loss need --controller-remote or --plant-remote"
                    );
                }
                if self.link_key.is_some() {
                    bail!("--link-key needs --controller-remote or --plant-remote");
                }
                return Ok(());
            }
        };
        let role = link.remote;
        let flag = format!("--{role}-remote");
        let bridge = exe_dir()?.join("deltaloop-bridge");
        let near = vec![bridge.display().to_string(), "near".into()];
        let command = match role {
            RemoteSide::Plant => &mut cfg.plant.command,
            RemoteSide::Controller => &mut cfg.controller.command,
        };
        // A run folder's config holds the near bridge already: it is replaced by this one's.
        let ours = command
            .first()
            .is_some_and(|p| p.ends_with("deltaloop-bridge"))
            && command.get(1).is_some_and(|a| a == "near");
        if !command.is_empty() && !ours {
            bail!(
                "{flag} and a {role} command (--{role}-cmd or {role}.command) exclude each other: give the command to `deltaloop join --role {role} --{role}-cmd` on the other host"
            );
        }
        *command = near;
        let key = match &self.link_key {
            Some(path) => install_link_key(LinkKey::read(path).map_err(anyhow::Error::msg)?),
            None => one_time_link_key()?,
        };
        if !self.quiet {
            eprintln!("{}", self.join_hint(role, &link.listen, key));
        }
        cfg.link = Some(link);
        Ok(())
    }

    /// How the other host joins: the exact `deltaloop join` command, with the key file's name or
    /// the one-time key.
    fn join_hint(&self, role: RemoteSide, endpoint: &str, key: &LinkKey) -> String {
        match &self.link_key {
            Some(p) => format!(
                "deltaloop: the {role} joins from the other host with: deltaloop join {endpoint} --role {role} --link-key {} (a copy of this key file there; key {})",
                p.display(),
                key.fingerprint()
            ),
            None => format!(
                "deltaloop: the {role} joins from the other host with (a one-time key for this run; --link-key FILE uses a key of yours):\n  deltaloop join {endpoint} --role {role} --link-token {}",
                key.to_hex()
            ),
        }
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

    /// Everything a run with these flags needs of its mode, config and other flags, checked
    /// before anything is written (regression: `--link-spin-us 151` was refused by the near
    /// bridge after the run folder existed, and `--sensitivity` blamed a `controller.command` the
    /// user never gave).
    pub fn check_run(&self, mode: LoopMode, cfg: &RunConfig, sensitivity: bool) -> Result<()> {
        self.check_mode(mode)?;
        let Some(link) = &cfg.link else {
            return Ok(());
        };
        let flag = format!("--{}-remote", link.remote.name());
        if mode == LoopMode::Inproc {
            bail!("{flag} needs --mode lockstep or realtime (inproc has no processes)");
        }
        let budget = cfg.loop_.torque_budget_us;
        if mode == LoopMode::Realtime && link.spin_us > budget {
            bail!(
                "--link-spin-us {}: allowed 0..={budget} (loop.torque_budget_us) in realtime",
                link.spin_us
            );
        }
        if sensitivity {
            bail!(
                "--sensitivity with {flag}: the round-off twin reruns the law with the built-in processes on this host; run the twin without {flag}"
            );
        }
        Ok(())
    }
}

/// `deltaloop join`: what to run on the other host.
pub struct Join<'a> {
    pub endpoint: &'a str,
    /// `controller` or `plant`.
    pub role: RemoteSide,
    pub controller_cmd: Option<&'a str>,
    pub plant_cmd: Option<&'a str>,
    pub runs: u32,
    pub wait_s: u64,
    pub spin_us: u32,
    /// The link key: a key file, or the token `deltaloop run` printed.
    pub link_key: Option<&'a Path>,
    pub link_token: Option<&'a str>,
    /// The far process's CPU (−1: not pinned) and SCHED_FIFO priority (0: SCHED_OTHER), this
    /// host's, not the run config's (None: the mode's default layout).
    pub cpu: Option<i32>,
    pub priority: Option<i32>,
}

/// The key `join` was given; one line if it was given none, both, or a bad one.
fn join_key(j: &Join<'_>) -> Result<LinkKey> {
    match (j.link_key, j.link_token) {
        (Some(p), None) => LinkKey::read(p).map_err(anyhow::Error::msg),
        (None, Some(t)) => LinkKey::from_hex(t).map_err(|e| anyhow::anyhow!("--link-token: {e}")),
        (Some(_), Some(_)) => bail!("--link-key and --link-token exclude each other: give one"),
        (None, None) => bail!(
            "deltaloop join needs the run's link key: --link-key FILE (a copy of the file given to `deltaloop run --link-key`) or --link-token HEX (printed by `deltaloop run` on the supervisor's host)"
        ),
    }
}

/// Replaces this process with `deltaloop-bridge far` (its exit code is the far process's);
/// returns only if that cannot start.
pub fn join(j: &Join<'_>) -> Result<()> {
    let addr = parse_endpoint(j.endpoint).map_err(|e| anyhow::anyhow!("deltaloop join: {e}"))?;
    far_command(j.role, j.controller_cmd, j.plant_cmd).map_err(anyhow::Error::msg)?;
    let key = join_key(j)?;
    let bridge = exe_dir()?.join("deltaloop-bridge");
    let mut c = Command::new(&bridge);
    c.env(KEY_ENV, key.to_hex());
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
    if let Some(cpu) = j.cpu {
        c.arg(format!("--cpu={cpu}"));
    }
    if let Some(p) = j.priority {
        c.arg(format!("--priority={p}"));
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
    use deltaloop_config::RemoteSide;

    fn cfg() -> RunConfig {
        RunConfig::from_file(std::path::Path::new(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../../configs/s1-nominal.toml"
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
        let link = c.link.unwrap();
        assert_eq!(
            (link.remote, link.listen.as_str()),
            (RemoteSide::Controller, "127.0.0.1:7447")
        );
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
            emulation: LinkEmulation {
                loss: 0.1,
                ..Default::default()
            },
            ..Default::default()
        };
        let e = lossy.apply(&mut cfg()).unwrap_err().to_string();
        assert!(
            e.contains("need --controller-remote or --plant-remote"),
            "{e}"
        );
        // The flags' emulation is checked by the config's one check, named as flags.
        let too_lossy = RemoteArgs {
            controller_remote: Some("127.0.0.1:7447".into()),
            emulation: LinkEmulation {
                loss: 2.0,
                ..Default::default()
            },
            ..Default::default()
        };
        let e = too_lossy.apply(&mut cfg()).unwrap_err().to_string();
        assert_eq!(
            e,
            "--link-loss 2: allowed 0 <= loss <= 1 (a fraction of the datagrams)"
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
        assert_eq!(c.link.as_ref().unwrap().remote, RemoteSide::Plant);
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
            link_key: None,
            link_token: None,
            cpu: None,
            priority: None,
        };
        for (role, c, p, says) in [
            (
                RemoteSide::Plant,
                Some("ctl"),
                None,
                "--controller-cmd with --role plant",
            ),
            (
                RemoteSide::Controller,
                None,
                Some("pl"),
                "--plant-cmd with --role controller",
            ),
            (RemoteSide::Plant, None, Some("  "), "--plant-cmd is empty"),
        ] {
            let e = join(&j(role, c, p)).unwrap_err().to_string();
            assert!(e.contains(says) && !e.contains('\n'), "{e}");
        }
    }

    #[test]
    fn regression_remote_run_flags_are_checked_before_the_run_folder_exists() {
        let remote = RemoteArgs {
            controller_remote: Some("127.0.0.1:7447".into()),
            spin_us: 151,
            quiet: true,
            ..Default::default()
        };
        let mut c = cfg();
        remote.apply(&mut c).unwrap();
        let e = remote
            .check_run(LoopMode::Realtime, &c, false)
            .unwrap_err()
            .to_string();
        assert!(e.contains("--link-spin-us 151: allowed 0..=150"), "{e}");
        remote.check_run(LoopMode::Lockstep, &c, false).unwrap();
        let e = remote
            .check_run(LoopMode::Lockstep, &c, true)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("--sensitivity with --controller-remote")
                && !e.contains("controller.command"),
            "{e}"
        );
    }

    /// Regression: where the remote process ran and how the link was emulated lived only in the
    /// near bridge's command line, which the report parsed back by strings. It is the config's
    /// typed `[link]` now: the run folder's config.toml keeps it, the report reads it, a bad
    /// value in a scenario file is refused naming its key, and a run folder's config runs again
    /// as the same remote run.
    #[test]
    fn regression_remote_placement_is_typed_in_the_config() {
        let remote = RemoteArgs {
            plant_remote: Some("127.0.0.1:7447".into()),
            emulation: LinkEmulation {
                delay_us: 40.0,
                loss: 0.01,
                seed: 7,
                ..Default::default()
            },
            quiet: true,
            ..Default::default()
        };
        let mut c = cfg();
        remote.apply(&mut c).unwrap();
        assert_eq!(c.plant.command.len(), 2, "{:?}", c.plant.command);
        assert_eq!(c.plant.command[1], "near");
        let back = RunConfig::from_toml_str(&c.to_toml_string(), None).unwrap();
        assert_eq!(back.link, c.link);
        let note = deltaloop_report::link::note(&back).unwrap();
        assert!(
            note.starts_with("plant on another host, across the link at 127.0.0.1:7447")
                && note.contains("delay 40 µs, jitter 0 µs, loss 0.01, seed 7"),
            "{note}"
        );
        // The same config again, no flags: the same remote run.
        let mut again = back.clone();
        RemoteArgs {
            quiet: true,
            ..Default::default()
        }
        .apply(&mut again)
        .unwrap();
        assert_eq!(
            (again.link, again.plant.command),
            (back.link, back.plant.command)
        );
        let text = "[scenario]\npath = \"s1\"\n[link]\nremote = \"controller\"\nlisten = \"10.0.0.1:7447\"\nloss = 1.5\n";
        let e = RunConfig::from_toml_str(text, None)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("link.loss") && e.contains("0 <= loss <= 1"),
            "{e}"
        );
        let text = text.replace("loss = 1.5", "listen2 = 1");
        assert!(RunConfig::from_toml_str(&text, None).is_err());
    }

    /// No unauthenticated mode: `join` without a key, with both, or with a bad token says so
    /// in one line; `run` refuses `--link-key` without a remote process, and a key file others
    /// can read.
    #[test]
    fn join_and_run_need_a_good_link_key() {
        let j = |link_key, link_token| Join {
            endpoint: "127.0.0.1:7447",
            role: RemoteSide::Controller,
            controller_cmd: None,
            plant_cmd: None,
            runs: 1,
            wait_s: 1,
            spin_us: 0,
            link_key,
            link_token,
            cpu: None,
            priority: None,
        };
        let one_line = |e: anyhow::Error, says: &str| {
            let e = e.to_string();
            assert!(e.contains(says) && !e.contains('\n'), "{e}");
        };
        one_line(
            join(&j(None, None)).unwrap_err(),
            "needs the run's link key",
        );
        one_line(
            join(&j(Some(Path::new("/nonexistent.key")), Some("ab"))).unwrap_err(),
            "exclude each other",
        );
        one_line(
            join(&j(None, Some("abc"))).unwrap_err(),
            "--link-token: a link key is 64 hex digits",
        );
        let d = tempfile::tempdir().unwrap();
        let open = d.path().join("open.key");
        std::fs::write(&open, format!("{}\n", "ab".repeat(32))).unwrap();
        use std::os::unix::fs::PermissionsExt;
        std::fs::set_permissions(&open, std::fs::Permissions::from_mode(0o644)).unwrap();
        one_line(join(&j(Some(&open), None)).unwrap_err(), "chmod 600");
        let lone = RemoteArgs {
            link_key: Some(open.clone()),
            ..Default::default()
        };
        one_line(
            lone.apply(&mut cfg()).unwrap_err(),
            "--link-key needs --controller-remote or --plant-remote",
        );
        let remote = RemoteArgs {
            controller_remote: Some("127.0.0.1:7447".into()),
            link_key: Some(open),
            quiet: true,
            ..Default::default()
        };
        one_line(remote.apply(&mut cfg()).unwrap_err(), "chmod 600");
    }
}
