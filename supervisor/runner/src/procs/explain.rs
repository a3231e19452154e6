//! `--explain` around one law's realtime run: the kernel's record of the loop's CPUs from before
//! START to the end, then each missed or late tick's cause (`deltaloop_timing::explain`).

use super::children::Pair;
use deltaloop_config::{LoopMode, RemoteSide, RunConfig};
use deltaloop_sched::{Counts, Recorder};
use deltaloop_timing::Timing;
use deltaloop_timing::explain::{LoopThreads, MissLog};
use std::path::{Path, PathBuf};

/// A law's explanation, being recorded.
pub(super) struct Explaining {
    /// None: this host cannot record (the warning said why); every cause is `unknown`.
    recorder: Option<Recorder>,
    record: PathBuf,
    threads: LoopThreads,
    budget_ns: u64,
}

/// The warning of a run that asked for `--explain` and gets no kernel record.
fn warning(why: &str) -> String {
    format!("--explain: {why}; the run goes on, and its misses' causes are `unknown`")
}

impl Explaining {
    /// Starts the kernel's record for a realtime run that asked for it (`record.explain`),
    /// with the miss log `timing` gets; None (with a warning in `warnings` when it was asked
    /// for and cannot be) otherwise.
    pub(super) fn start(
        cfg: &RunConfig,
        mode: LoopMode,
        pair: &Pair,
        run_dir: &Path,
        law: &str,
        warnings: &mut Vec<String>,
    ) -> Option<(Self, MissLog)> {
        if !cfg.record.explain || mode != LoopMode::Realtime {
            return None;
        }
        let layout = mode.layout(cfg)?;
        let across = deltaloop_report::link::across(cfg);
        if across == Some(RemoteSide::Plant) {
            warnings.push(
                "--explain: the plant runs on the other host, and the kernel there is not recorded; nothing is explained"
                    .into(),
            );
            return None;
        }
        let (plant_pid, controller_pid) = pair.pids();
        let (Some(plant_cpu), Some(plant_pid)) = (layout.plant_cpu, plant_pid) else {
            warnings.push("--explain: the plant is not pinned to a CPU ([loop.realtime] plant_cpu); nothing is explained".into());
            return None;
        };
        let controller = match (across, layout.controller_cpu, controller_pid) {
            (Some(RemoteSide::Controller), _, _) => None,
            (None, Some(cpu), Some(pid)) => Some((pid as i32, cpu)),
            _ => {
                warnings.push("--explain: the controller is not pinned to a CPU ([loop.realtime] controller_cpu); nothing is explained".into());
                return None;
            }
        };
        let threads = LoopThreads {
            plant: (plant_pid as i32, plant_cpu),
            controller,
        };
        let record = run_dir.join(format!(".{law}.sched.txt"));
        let log = match MissLog::create(&run_dir.join(format!(".{law}.misses.tmp")), cfg.ts_ns()) {
            Ok(l) => l,
            Err(e) => {
                warnings.push(warning(&format!("{e:#}")));
                return None;
            }
        };
        let mut cpus = vec![plant_cpu];
        cpus.extend(controller.map(|c| c.1).filter(|&c| c != plant_cpu));
        let recorder = match Recorder::start(&cpus, &record) {
            Ok(r) => Some(r),
            Err(why) => {
                warnings.push(warning(&why));
                None
            }
        };
        Some((
            Self {
                recorder,
                record,
                threads,
                budget_ns: u64::from(cfg.loop_.torque_budget_us) * 1000,
            },
            log,
        ))
    }

    /// Stops the record and explains the run's missed and late ticks into `timing` and the
    /// run folder; a failure is a warning in `warnings`, never a failed run.
    pub(super) fn finish(
        self,
        timing: &mut Timing,
        run_dir: &Path,
        law: &str,
        warnings: &mut Vec<String>,
    ) {
        let counts = match self.recorder.map(Recorder::stop) {
            Some(Ok(c)) => c,
            Some(Err(why)) => {
                warnings.push(warning(&why));
                Counts::default()
            }
            None => Counts::default(),
        };
        if !self.record.exists()
            && let Err(e) = std::fs::write(&self.record, "")
        {
            warnings.push(warning(&format!("{}: {e}", self.record.display())));
            return;
        }
        let Some(log) = timing.miss_log.take() else {
            return;
        };
        match deltaloop_timing::explain::explain(
            run_dir,
            law,
            (&self.record, counts),
            &log,
            self.threads,
            self.budget_ns,
        ) {
            Ok(x) => timing.explained = Some(x),
            Err(e) => warnings.push(format!("--explain: {e:#}")),
        }
    }
}
