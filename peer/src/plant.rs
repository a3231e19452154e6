//! A plant in C: `dl_plant_main` with the five functions of a [`DlPlantFns`]. The library runs
//! the built-in plant process's loop around them (its clock, the arrival rule, misses and the
//! silence stop, telemetry, the final state, STOP, the safe stop); the functions are the physics:
//! the project's own model (`dl_model_*`), another model, or a rig's drives and encoders.

use std::ffi::{c_char, c_int, c_void};

use deltaloop_link::Handoff;
use deltaloop_model::{PlantSample, Vec3};
use deltaloop_plant::process::serve;
use deltaloop_plant::tick::{Drives, Physics};
use deltaloop_transport::args::LoopArgs;
use deltaloop_transport::exit::ProcessEnd;

use crate::controller::DlInitFn;
use crate::error::refusal;
use crate::model::{DlJoints, drives_of};
use crate::process::main_of;
use crate::run::DlRun;

/// What a plant in C does; `user` is the pointer given to [`dl_plant_main`]. Each returns 0, or
/// non-zero with a message in [`dl_set_error`](crate::dl_set_error).
#[repr(C)]
pub struct DlPlantFns {
    /// Once before READY with the run (may be null): open the drives, read the constants.
    /// Non-zero refuses the run (set-up failed: exit 3).
    pub init: DlInitFn,
    /// After START (may be null): the robot is at rest at `q0` (3 joint angles, rad), tick 0.
    /// Non-zero: set-up failed (exit 3).
    pub start:
        Option<unsafe extern "C" fn(user: *mut c_void, run: *const DlRun, q0: *const f64) -> c_int>,
    /// The true state now (no sensor noise): q (rad), q̇ (rad/s), τᵃ (N m) applied over the last
    /// interval (at tick 0 the holding torque). May be called more than once a tick. Non-zero:
    /// the plant failed (a plant error, not the law's divergence: the run ends as a plant fault
    /// quoting the message, after a safe stop, exit 4).
    pub truth: Option<unsafe extern "C" fn(user: *mut c_void, out: *mut DlJoints) -> c_int>,
    /// What the encoders report now: called once for each state published (after `truth`), it
    /// may advance a noise stream. Non-zero: the plant failed, as for `truth`.
    pub measure: Option<unsafe extern "C" fn(user: *mut c_void, out: *mut DlJoints) -> c_int>,
    /// Runs one tick's interval [t_k, t_k + Ts): `tau` (3 torques, N m) is tick k's command,
    /// reaching the drives `latency_ns` after t_k plus the configured transport delay; null when
    /// none arrived (the drives hold). Sets `*drives` to `DL_DRIVES_*` bits. Non-zero: the plant
    /// failed (diverged: the run ends with no safe stop, exit 4).
    pub advance: Option<
        unsafe extern "C" fn(
            user: *mut c_void,
            tau: *const f64,
            latency_ns: u64,
            drives: *mut u32,
        ) -> c_int,
    >,
    /// One tick of safe stop after a fault or STOP: τ = G(q) − `damping` q̇ (N m s/rad), no
    /// controller. Null: no braking (the safe stop ends at once).
    pub brake: Option<unsafe extern "C" fn(user: *mut c_void, damping: f64) -> c_int>,
}

type JointsFn = unsafe extern "C" fn(*mut c_void, *mut DlJoints) -> c_int;
type AdvanceFn = unsafe extern "C" fn(*mut c_void, *const f64, u64, *mut u32) -> c_int;

/// A C plant, as the process's [`Physics`]: the library counts its ticks.
struct CPhysics {
    truth: JointsFn,
    measure: JointsFn,
    advance: AdvanceFn,
    brake: Option<unsafe extern "C" fn(*mut c_void, f64) -> c_int>,
    user: *mut c_void,
    tick: u64,
}

impl CPhysics {
    /// `f`'s joints now, as tick k's sample, or the plant's error (its message and code): the
    /// loop stops on it (a plant error), never taking zeros for the robot's state.
    fn joints(&self, f: JointsFn) -> Result<PlantSample, String> {
        let mut j = DlJoints::default();
        // SAFETY: valid functions accepting `user` (the caller of dl_plant_main promised).
        let rc = unsafe { f(self.user, &mut j) };
        if rc != 0 {
            return Err(refusal(rc));
        }
        Ok(PlantSample {
            k: self.tick,
            q: Vec3::from(j.q),
            qd: Vec3::from(j.qd),
            tau_applied: Vec3::from(j.tau_applied),
        })
    }
}

impl Physics for CPhysics {
    fn tick(&self) -> u64 {
        self.tick
    }
    fn sample(&self) -> Result<PlantSample, String> {
        self.joints(self.truth)
    }
    fn measure(&mut self) -> Result<PlantSample, String> {
        self.joints(self.measure)
    }
    fn advance_after(&mut self, cmd: Option<Vec3>, latency_ns: u64) -> Result<Drives, String> {
        let tau: Option<[f64; 3]> = cmd.map(Into::into);
        let mut bits = 0u32;
        let p = tau.as_ref().map_or(std::ptr::null(), |t| t.as_ptr());
        // SAFETY: as above; `p` is null or 3 doubles, `bits` writable.
        let rc = unsafe { (self.advance)(self.user, p, latency_ns, &mut bits) };
        if rc != 0 {
            return Err(format!("the plant failed: {}", refusal(rc)));
        }
        self.tick += 1;
        Ok(drives_of(bits))
    }
    fn brake_tick(&mut self, damping: f64) -> Result<(), String> {
        if let Some(brake) = self.brake {
            // SAFETY: as above.
            let rc = unsafe { brake(self.user, damping) };
            if rc != 0 {
                return Err(format!("the brake failed: {}", refusal(rc)));
            }
        }
        self.tick += 1;
        Ok(())
    }
}

/// The arguments of a plant process: the loop's.
#[derive(clap::Parser, Debug)]
#[command(about = "a deltaloop plant process (started by `deltaloop run --plant-cmd`)")]
struct Args {
    #[command(flatten)]
    run: LoopArgs,
}

/// The plant process of the run the arguments name (`--run-id ID --config FILE --mode
/// lockstep|realtime`, as the supervisor gives them): `init` once with the run, `start` at
/// START, then `truth`, `measure` and `advance` every tick until the run ends, and `brake` for
/// the safe stop. Returns the exit code for `main` to return (0 done, 2 bad arguments, 3 set-up
/// failed, 4 fault, 5 stopped: docs/protocol.md §10), having printed one line on stderr (and set
/// it as [`dl_last_error`](crate::dl_last_error)) for every code but 0. The process's name in its
/// messages: argv[0]. From C's `main`:
/// `return dl_plant_main(argc, (const char *const *)argv, &fns, &rig);`
///
/// On the caller's behalf, as the built-in plant: the `[loop.<mode>]` layout (SCHED_FIFO at
/// `plant_priority`, pinning to `plant_cpu`, `mlockall` with `lock_memory`, applied after
/// `init`), the clock, the silence rule, the safe stop and the signals. Every function runs on
/// the calling thread, one at a time; those of the loop under its scheduling, within the tick's
/// deadline: no blocking, no allocation, no system call, no printing.
///
/// # Safety
/// `argv` holds `argc` valid C strings; `fns` points to a `dl_plant_fns` whose non-null
/// functions are valid and accept `user` (passed through untouched).
#[unsafe(no_mangle)]
pub unsafe extern "C" fn dl_plant_main(
    argc: c_int,
    argv: *const *const c_char,
    fns: *const DlPlantFns,
    user: *mut c_void,
) -> c_int {
    // SAFETY: as the caller promised.
    unsafe {
        main_of(argc, argv, |args, name| {
            plant_main(args, name, fns.as_ref(), user)
        })
    }
}

/// How the plant process ended, or the usage error of a null function.
fn plant_main(
    args: Args,
    name: &str,
    fns: Option<&DlPlantFns>,
    user: *mut c_void,
) -> Result<anyhow::Result<ProcessEnd>, &'static str> {
    let Some((fns, truth, measure, advance)) =
        fns.and_then(|f| Some((f, f.truth?, f.measure?, f.advance?)))
    else {
        return Err("dl_plant_main: fns, or its truth, measure or advance, is null");
    };
    let term = deltaloop_transport::rt::child_signals();
    let end = serve(&args.run, &term, name, Handoff::default(), |cfg| {
        let run = DlRun::new(cfg, &args.run, "")?;
        if let Some(init) = fns.init {
            // SAFETY: a valid function accepting `user`; `run` lives through the call.
            let rc = unsafe { init(user, &run) };
            if rc != 0 {
                anyhow::bail!("the plant refused the run: {}", refusal(rc));
            }
        }
        let start = fns.start;
        Ok(move |q0: Vec3| {
            if let Some(start) = start {
                let q0: [f64; 3] = q0.into();
                // SAFETY: as above; `q0` is 3 doubles.
                let rc = unsafe { start(user, &run, q0.as_ptr()) };
                if rc != 0 {
                    anyhow::bail!("the plant could not start: {}", refusal(rc));
                }
            }
            Ok(CPhysics {
                truth,
                measure,
                advance,
                brake: fns.brake,
                user,
                tick: 0,
            })
        })
    });
    Ok(end)
}
