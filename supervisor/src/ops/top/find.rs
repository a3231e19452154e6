//! Which runs are live on this machine, and what they run: run ids from the iceoryx2 nodes that
//! are alive (`deltaloop-plant-<run id>`), and the law, mode and config of a run from the command
//! lines of its processes (every loop process gets `--run-id`, `--config`, `--mode`, and the
//! controller `--law`: docs/protocol.md §11).

use deltaloop_config::{Law, LoopMode};
use deltaloop_transport::ipc;
use std::path::PathBuf;

/// The node name prefix of a run's plant: the plant publishes everything `top` reads, so a run
/// is live while its plant's node is.
const PLANT_NODE: &str = "deltaloop-plant-";

/// Run ids whose plant node is alive, sorted.
pub fn live_run_ids() -> Vec<String> {
    let mut ids: Vec<String> = ipc::alive_node_names()
        .into_iter()
        .filter_map(|n| n.strip_prefix(PLANT_NODE).map(str::to_string))
        .collect();
    ids.sort();
    ids.dedup();
    ids
}

/// Whether run `run_id`'s plant node is alive.
pub fn is_live(run_id: &str) -> bool {
    live_run_ids().iter().any(|r| r == run_id)
}

/// Removes the iceoryx2 resources of the dead observers of `run_id` (its nodes other than the
/// run's own plant, controller and supervisor, which the supervisor cleans and reports itself);
/// returns their names.
pub fn remove_dead_observers(run_id: &str) -> Vec<String> {
    ipc::remove_dead_nodes_where(&|name| is_observer_of(name, run_id))
}

/// Whether node `name` belongs to run `run_id` without being one of its loop processes.
fn is_observer_of(name: &str, run_id: &str) -> bool {
    let Some(role) = name
        .strip_prefix("deltaloop-")
        .and_then(|n| n.strip_suffix(run_id))
        .and_then(|n| n.strip_suffix('-'))
    else {
        return false;
    };
    !matches!(role, "plant" | "controller" | "supervisor")
}

/// What the command lines of a run's processes say about it (None: not found, e.g. a process in
/// another PID namespace).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct RunInfo {
    pub run_id: String,
    pub law: Option<Law>,
    pub mode: Option<LoopMode>,
    /// The resolved config the children read (`<run folder>/config.toml`).
    pub config: Option<PathBuf>,
}

impl RunInfo {
    /// Fills in what one process's arguments say, if they carry `--run-id <run_id>`.
    pub fn learn_from(&mut self, args: &[String]) {
        let value = |flag: &str| {
            args.iter()
                .position(|a| a == flag)
                .and_then(|i| args.get(i + 1))
        };
        if value("--run-id") != Some(&self.run_id) {
            return;
        }
        if let Some(l) = value("--law").and_then(|l| Law::parse(l).ok()) {
            self.law = Some(l);
        }
        if let Some(m) = value("--mode").and_then(|m| LoopMode::parse(m).ok()) {
            self.mode = Some(m);
        }
        if let Some(c) = value("--config") {
            self.config = Some(PathBuf::from(c));
        }
    }

    /// One line for a list of runs.
    pub fn describe(&self) -> String {
        format!(
            "{}  law {}  mode {}  config {}",
            self.run_id,
            self.law.map_or("?".into(), |l| l.to_string()),
            self.mode.map_or("?", LoopMode::name),
            self.config
                .as_ref()
                .map_or("?".into(), |c| c.display().to_string())
        )
    }
}

/// Reads `/proc/*/cmdline` for the processes of `run_id`.
pub fn run_info(run_id: &str) -> RunInfo {
    let mut info = RunInfo {
        run_id: run_id.to_string(),
        ..RunInfo::default()
    };
    let Ok(dir) = std::fs::read_dir("/proc") else {
        return info;
    };
    for entry in dir.flatten() {
        if !entry
            .file_name()
            .to_string_lossy()
            .bytes()
            .all(|b| b.is_ascii_digit())
        {
            continue;
        }
        let Ok(raw) = std::fs::read(entry.path().join("cmdline")) else {
            continue;
        };
        if !raw.windows(run_id.len()).any(|w| w == run_id.as_bytes()) {
            continue;
        }
        let args: Vec<String> = raw
            .split(|&b| b == 0)
            .map(|a| String::from_utf8_lossy(a).into_owned())
            .collect();
        info.learn_from(&args);
    }
    info
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_a_runs_observers_are_reclaimed() {
        assert!(is_observer_of("deltaloop-top-ab-1", "ab-1"));
        for other in [
            "deltaloop-plant-ab-1",
            "deltaloop-controller-ab-1",
            "deltaloop-supervisor-ab-1",
            "deltaloop-top-ab-12",
            "deltaloop-top-xab-1x",
            "someone-else",
        ] {
            assert!(!is_observer_of(other, "ab-1"), "{other}");
        }
    }

    fn args(s: &str) -> Vec<String> {
        s.split(' ').map(str::to_string).collect()
    }

    /// The plant says mode and config, the controller the law too; another run's process and a
    /// flag without a value say nothing.
    #[test]
    fn run_info_comes_from_the_run_s_own_command_lines() {
        let mut i = RunInfo {
            run_id: "ab-1".into(),
            ..RunInfo::default()
        };
        i.learn_from(&args(
            "deltaloop-plant --run-id ab-1 --config /r/config.toml --mode lockstep",
        ));
        i.learn_from(&args(
            "deltaloop-controller --run-id ab-2 --law pid --mode realtime",
        ));
        assert_eq!(i.law, None);
        i.learn_from(&args(
            "ctl --run-id ab-1 --mode lockstep --law tdc-is-sta --config",
        ));
        assert_eq!(i.mode, Some(LoopMode::Lockstep));
        assert_eq!(i.law, Some(Law::TdcIsSta));
        assert_eq!(i.config, Some(PathBuf::from("/r/config.toml")));
        assert!(i.describe().contains("law tdc-is-sta  mode lockstep"));
    }
}
