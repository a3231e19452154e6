//! A controller in C: `dl_controller_main` with an `init` and a `step`.

use std::ffi::{c_char, c_int, c_void};

use deltaloop_controller::process::{Step, serve};
use deltaloop_link::Handoff;
use deltaloop_transport::args::LoopArgs;
use deltaloop_transport::exit::ProcessEnd;
use deltaloop_wire::{RefSample, StateMsg, TorqueMsg};

use crate::error::refusal;
use crate::process::main_of;
use crate::run::DlRun;

/// Called once before READY with the run: read the constants, allocate what the step needs.
/// Return 0, or non-zero to refuse the run (set-up failed: exit 3), saying why with
/// [`dl_set_error`](crate::dl_set_error).
pub type DlInitFn = Option<unsafe extern "C" fn(user: *mut c_void, run: *const DlRun) -> c_int>;

/// Called for each tick k with the plant's state k and tick k's reference row: fill `reply`'s
/// `tau` (the command, N m), and `s`, `n_hat`, `u` (the law's internals, for the trace; zero if
/// none). The library sets the tick and every time stamp. Return 0, or non-zero to end the run
/// with a fault at this tick (exit 4), saying why with [`dl_set_error`](crate::dl_set_error):
/// the library tells the plant at once (it stops the loop at its next tick, naming the error,
/// and brakes), and the run is a controller fault quoting the message.
pub type DlStepFn = Option<
    unsafe extern "C" fn(
        user: *mut c_void,
        state: *const StateMsg,
        reference: *const RefSample,
        reply: *mut TorqueMsg,
    ) -> c_int,
>;

/// The arguments of a controller process: the loop's and `--law`.
#[derive(clap::Parser, Debug)]
#[command(about = "a deltaloop controller process (started by `deltaloop run`)")]
struct Args {
    #[command(flatten)]
    run: LoopArgs,
    /// The law the run asks for (the controller may refuse one it does not implement).
    #[arg(long, default_value = "")]
    law: String,
}

/// A C step, as the process's [`Step`].
struct CStep {
    step: unsafe extern "C" fn(
        *mut c_void,
        *const StateMsg,
        *const RefSample,
        *mut TorqueMsg,
    ) -> c_int,
    user: *mut c_void,
    /// What `init` named the controller ([`dl_run_set_label`](crate::run::dl_run_set_label)).
    label: Option<String>,
}

impl Step for CStep {
    fn label(&self) -> Option<&str> {
        self.label.as_deref()
    }

    fn step(&mut self, state: &StateMsg, row: &RefSample) -> Result<TorqueMsg, String> {
        let mut reply = TorqueMsg {
            tick: state.tick,
            ..TorqueMsg::default()
        };
        // SAFETY: the caller of dl_controller_main promised a valid step and user pointer; the
        // three pointers are to live values of the types the header declares.
        let rc = unsafe { (self.step)(self.user, state, row, &mut reply) };
        if rc == 0 { Ok(reply) } else { Err(refusal(rc)) }
    }
}

/// The controller process of the run the arguments name (`--run-id ID --config FILE --mode
/// lockstep|realtime --law NAME`, as the supervisor gives them): `init` once with the run, then
/// `step` for every tick until the run ends. Returns the exit code for `main` to return (0 done,
/// 2 bad arguments, 3 set-up failed, 4 fault, 5 stopped, 6 the plant silent: docs/protocol.md
/// §10), having printed one line on stderr (and set it as [`dl_last_error`](crate::dl_last_error))
/// for every code but 0. The process's name in its messages: argv[0]. From C's `main`:
/// `return dl_controller_main(argc, (const char *const *)argv, init, step, &law);`
///
/// On the caller's behalf, as the built-in controller: `controller.compute_delay_us` (a busy-wait
/// after each `step`: do not add it again), the `[faults]` drills (`inject` stall, nan-torque,
/// panic), the `[loop.<mode>]` layout (SCHED_FIFO at `controller_priority`, pinning to
/// `controller_cpu`, `mlockall` with `lock_memory`, applied after `init`), and the signals
/// (SIGINT, SIGHUP ignored; SIGTERM a clean stop; SIGTERM on the parent's death).
///
/// `init` and `step` run on the calling thread, one at a time. Before each `step` the reply is
/// zeroed but for its tick. `step` runs under the layout's scheduling within the tick's deadline:
/// no blocking, no allocation, no system call, no printing (docs/guide/own-process.md).
///
/// # Safety
/// `argv` holds `argc` valid C strings; `init` (may be null) and `step` are valid functions that
/// accept `user` (passed through untouched).
#[unsafe(no_mangle)]
pub unsafe extern "C" fn dl_controller_main(
    argc: c_int,
    argv: *const *const c_char,
    init: DlInitFn,
    step: DlStepFn,
    user: *mut c_void,
) -> c_int {
    // SAFETY: as the caller promised.
    unsafe {
        main_of(argc, argv, |args, name| {
            controller_main(args, name, init, step, user)
        })
    }
}

/// How the controller process ended, or the usage error of a null step function.
fn controller_main(
    args: Args,
    name: &str,
    init: DlInitFn,
    step: DlStepFn,
    user: *mut c_void,
) -> Result<anyhow::Result<ProcessEnd>, &'static str> {
    let Some(step) = step else {
        return Err("dl_controller_main: the step function is null");
    };
    let term = deltaloop_transport::rt::child_signals();
    let end = serve(&args.run, &term, name, Handoff::default(), |cfg| {
        let run = DlRun::new(cfg, &args.run, &args.law)?;
        if let Some(init) = init {
            // SAFETY: a valid function accepting `user` (the caller's promise); `run` lives
            // through the call.
            let rc = unsafe { init(user, &run) };
            if rc != 0 {
                anyhow::bail!("the controller refused the run: {}", refusal(rc));
            }
        }
        Ok(CStep {
            step,
            user,
            label: run.label(),
        })
    });
    Ok(end)
}
