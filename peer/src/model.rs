//! The project's own Delta robot model (dynamics, drives, sensors: docs/delta-robot.md) for a
//! plant in C: `dl_model_open` builds it from the run exactly as the built-in plant does, and
//! `dl_model_truth`, `_measure`, `_advance` and `_brake` are a [`DlPlantFns`]'s functions, so a C
//! plant that forwards to them runs bit for bit as `deltaloop-plant` (examples/c-plant).
//!
//! [`DlPlantFns`]: crate::DlPlantFns

use std::ffi::c_int;

use deltaloop_model::{PlantSample, Vec3};
use deltaloop_plant::plant_from_config;
use deltaloop_plant::tick::{Drives, Physics};

use crate::error::{DL_BAD_ARGUMENT, DL_OK, set_error};
use crate::run::DlRun;

/// The drives clamped the command to ±τ_max in this interval.
pub const DL_DRIVES_CLAMPED: u32 = 1;
/// No command took effect in this interval: the drives held the last torque.
pub const DL_DRIVES_HELD: u32 = 2;
/// The drives rejected a command beyond ±τ_max (`faults.torque_limit = "reject"`).
pub const DL_DRIVES_REJECTED: u32 = 8;

/// A joint-space state: angles, rates, and the torque applied over the last interval.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct DlJoints {
    /// Joint angles q, rad.
    pub q: [f64; 3],
    /// Joint rates q̇, rad/s.
    pub qd: [f64; 3],
    /// Torque the drives applied over the last interval (τᵃ), N m.
    pub tau_applied: [f64; 3],
}

impl DlJoints {
    fn of(s: &PlantSample) -> Self {
        Self {
            q: s.q.into(),
            qd: s.qd.into(),
            tau_applied: s.tau_applied.into(),
        }
    }
}

/// `DL_DRIVES_*` bits as the plant side's drive flags.
pub(crate) fn drives_of(bits: u32) -> Drives {
    Drives {
        clamped: bits & DL_DRIVES_CLAMPED != 0,
        held: bits & DL_DRIVES_HELD != 0,
        rejected: bits & DL_DRIVES_REJECTED != 0,
    }
}

fn bits_of(d: Drives) -> u32 {
    (if d.clamped { DL_DRIVES_CLAMPED } else { 0 })
        | (if d.held { DL_DRIVES_HELD } else { 0 })
        | (if d.rejected { DL_DRIVES_REJECTED } else { 0 })
}

/// The project's plant model. Opaque: made by [`dl_model_open`], freed by [`dl_model_close`].
pub struct DlModel(deltaloop_model::Plant);

/// Builds the run's plant (`[plant]`, `[sensor]`, `[faults]`, `[loop]`) at rest at `q0` (3 joint
/// angles, rad) into `*out`. DL_OK, or DL_BAD_ARGUMENT (a null pointer, or q0 outside the
/// workspace: the message says which).
///
/// # Safety
/// `run` is the one `init` or `start` got, `q0` 3 readable doubles, `out` writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn dl_model_open(
    run: *const DlRun,
    q0: *const f64,
    out: *mut *mut DlModel,
) -> c_int {
    if run.is_null() || q0.is_null() || out.is_null() {
        set_error("dl_model_open: a null run, q0 or out");
        return DL_BAD_ARGUMENT;
    }
    // SAFETY: the caller's promises.
    let (run, q0) = unsafe { (&*run, Vec3::from(*q0.cast::<[f64; 3]>())) };
    match plant_from_config(&run.cfg, q0) {
        Ok(p) => {
            // SAFETY: writable (the caller's promise).
            unsafe { *out = Box::into_raw(Box::new(DlModel(p))) };
            DL_OK
        }
        Err(e) => {
            set_error(&format!("dl_model_open: q0 = {q0:?} rad: {e}"));
            DL_BAD_ARGUMENT
        }
    }
}

/// Frees a model (null: nothing).
///
/// # Safety
/// `m` is null or from [`dl_model_open`], not used after.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn dl_model_close(m: *mut DlModel) {
    if !m.is_null() {
        // SAFETY: made by Box::into_raw in dl_model_open.
        drop(unsafe { Box::from_raw(m) });
    }
}

/// Runs `f` on a model and writes what it gives to `out`, or DL_BAD_ARGUMENT on a null pointer
/// or a failure (its message in `dl_last_error`).
unsafe fn with<T>(
    m: *mut DlModel,
    out: *mut T,
    f: impl FnOnce(&mut deltaloop_model::Plant) -> Result<T, String>,
) -> c_int {
    // SAFETY: null or valid (the caller's promise).
    let (Some(m), Some(out)) = (unsafe { m.as_mut() }, unsafe { out.as_mut() }) else {
        set_error("a null model or output");
        return DL_BAD_ARGUMENT;
    };
    match f(&mut m.0) {
        Ok(v) => {
            *out = v;
            DL_OK
        }
        Err(e) => {
            set_error(&e);
            DL_BAD_ARGUMENT
        }
    }
}

/// The true state now (`dl_plant_fns.truth`).
///
/// # Safety
/// `m` from [`dl_model_open`], `out` writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn dl_model_truth(m: *mut DlModel, out: *mut DlJoints) -> c_int {
    // SAFETY: forwarded promises.
    unsafe { with(m, out, |p| Physics::sample(p).map(|s| DlJoints::of(&s))) }
}

/// What the sensors report now, advancing the noise stream (`dl_plant_fns.measure`).
///
/// # Safety
/// As [`dl_model_truth`].
#[unsafe(no_mangle)]
pub unsafe extern "C" fn dl_model_measure(m: *mut DlModel, out: *mut DlJoints) -> c_int {
    // SAFETY: forwarded promises.
    unsafe { with(m, out, |p| Physics::measure(p).map(|s| DlJoints::of(&s))) }
}

/// Runs one interval (`dl_plant_fns.advance`): `tau` null or 3 torques (N m) reaching the drives
/// `latency_ns` after the tick plus the transport delay; `*drives` gets `DL_DRIVES_*` bits.
/// DL_OK, or DL_BAD_ARGUMENT with the model's failure (left the workspace, non-finite state).
///
/// # Safety
/// `m` from [`dl_model_open`], `tau` null or 3 readable doubles, `drives` writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn dl_model_advance(
    m: *mut DlModel,
    tau: *const f64,
    latency_ns: u64,
    drives: *mut u32,
) -> c_int {
    // SAFETY: null or 3 doubles (the caller's promise).
    let cmd = (!tau.is_null()).then(|| Vec3::from(unsafe { *tau.cast::<[f64; 3]>() }));
    // SAFETY: forwarded promises.
    unsafe {
        with(m, drives, |p| {
            Physics::advance_after(p, cmd, latency_ns).map(bits_of)
        })
    }
}

/// One tick of safe stop (`dl_plant_fns.brake`): τ = G(q) − `damping` q̇, N m.
///
/// # Safety
/// `m` from [`dl_model_open`].
#[unsafe(no_mangle)]
pub unsafe extern "C" fn dl_model_brake(m: *mut DlModel, damping: f64) -> c_int {
    let mut unit = ();
    // SAFETY: forwarded promises.
    unsafe { with(m, &mut unit, |p| Physics::brake_tick(p, damping)) }
}

#[cfg(test)]
mod tests {
    use super::*;
    use deltaloop_wire as wire;

    /// The drive bits are the telemetry's (a C plant's bits reach the trace unchanged).
    #[test]
    fn drive_bits_are_the_telemetry_flags_and_round_trip() {
        assert_eq!(
            (DL_DRIVES_CLAMPED, DL_DRIVES_HELD, DL_DRIVES_REJECTED),
            (wire::TEL_CLAMPED, wire::TEL_HELD, wire::TEL_REJECTED)
        );
        for bits in 0..16 {
            let known = bits & (DL_DRIVES_CLAMPED | DL_DRIVES_HELD | DL_DRIVES_REJECTED);
            assert_eq!(bits_of(drives_of(bits)), known, "bits {bits}");
        }
    }
}
