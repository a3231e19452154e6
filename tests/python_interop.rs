//! A controller written in Python joins a deltaloop run: the `deltaloop` Python package
//! (`python/`: ctypes wire types and a controller helper over the iceoryx2 Python bindings) and the
//! `tdc` law of `examples/python-controller/controller.py`, run with `--controller-cmd`.
//!
//! The tests need Python ≥ 3.11 with its `venv` module; they set up a virtual environment in
//! `target/python-venv` (once, or again when it lacks the pinned iceoryx2 or holds an older copy
//! of `python/`), installing `python/requirements.txt` and `python/` with pip (network access to
//! PyPI the first time). Without Python they fail and say what to install; they never pass
//! silently.

mod common;

use common::python::{py_snippet, python, root, run_cmd, text};

use deltaloop_transport::ipc;
use deltaloop_transport::wire::{
    self, ControlKind, ControlMsg, RefSample, Sender, StateMsg, TelemetryMsg, TorqueMsg,
};
use iceoryx2::prelude::ZeroCopySend;
use serde_json::{Value, json};
use std::mem::{align_of, offset_of, size_of};
use std::process::Command;


/// The size of a field's type, through a projection `|m: &T| &m.field`.
fn field_size<T, F>(_: fn(&T) -> &F) -> usize {
    size_of::<F>()
}

fn field_type<T, F>(_: fn(&T) -> &F) -> &'static str {
    std::any::type_name::<F>()
}

/// One wire type as the Rust compiler lays it out, in the JSON shape the Python snippet prints.
macro_rules! layout {
    ($t:ident { $($f:ident),* $(,)? }) => {
        (stringify!($t), json!({
            // SAFETY: type_name only returns the name; the layout contract is what is checked here.
            "type_name": unsafe { <$t as ZeroCopySend>::type_name() },
            "size": size_of::<$t>(),
            "align": align_of::<$t>(),
            "fields": [$([
                stringify!($f),
                offset_of!($t, $f),
                field_size(|m: &$t| &m.$f),
                field_type(|m: &$t| &m.$f),
            ]),*],
        }))
    };
}

/// The ctypes mirrors in `deltaloop.wire` have the Rust types' type names, sizes, alignments,
/// and fields (name, offset, size, element type, order); the flag and kind constants agree.
#[test]
fn python_wire_types_match_the_rust_layouts() {
    let rust: serde_json::Map<String, Value> = [
        layout!(StateMsg {
            tick,
            flags,
            _pad,
            q,
            qd,
            tau_applied,
            q_true,
            qd_true,
            t_deadline_ns,
            t_wake_ns,
            t_publish_ns
        }),
        layout!(TorqueMsg {
            tick,
            skipped,
            tau,
            s,
            n_hat,
            u,
            t_state_rx_ns,
            t_publish_ns
        }),
        layout!(TelemetryMsg {
            tick,
            flags,
            _pad,
            t_deadline_ns,
            t_wake_ns,
            t_state_pub_ns,
            t_torque_rx_ns,
            late_dropped,
            misses,
            arrival_ns
        }),
        layout!(ControlMsg {
            kind,
            from,
            tick,
            ticks,
            q0,
            t0_ns,
            text
        }),
        layout!(RefSample { tick, q, qd, qdd }),
    ]
    .into_iter()
    .map(|(k, v)| (k.to_string(), v))
    .collect();
    let constants = json!({
        "STATE_FINAL": wire::STATE_FINAL,
        "TEL_CLAMPED": wire::TEL_CLAMPED,
        "TEL_HELD": wire::TEL_HELD,
        "TEL_MISSED": wire::TEL_MISSED,
        "TEL_REJECTED": wire::TEL_REJECTED,
        "TEL_SAFE_STOP": wire::TEL_SAFE_STOP,
        "READY": ControlKind::Ready as u32,
        "START": ControlKind::Start as u32,
        "STOP": ControlKind::Stop as u32,
        "FAULT": ControlKind::Fault as u32,
        "ARMED": ControlKind::Armed as u32,
        "DIVERGED": ControlKind::Diverged as u32,
        "FROM_PLANT": Sender::Plant as u32,
        "FROM_CONTROLLER": Sender::Controller as u32,
        "FROM_SUPERVISOR": Sender::Supervisor as u32,
        "REF_CHUNK": ipc::REF_CHUNK,
        "REF_RING": ipc::REF_RING,
        "LOOP_BUFFER": ipc::LOOP_BUFFER,
        "OBSERVER_BUFFER": ipc::OBSERVER_BUFFER,
        "HANDSHAKE_TIMEOUT_NS": ipc::HANDSHAKE_TIMEOUT_NS,
    });
    // Field types in Rust's spelling (`[f64; 3]`); `from_` is `from` (a Python keyword).
    let out = py_snippet(
        r#"
import ctypes, json
from deltaloop import controller, wire
def rust(t):
    if issubclass(t, ctypes.Array):
        return f"[{rust(t._type_)}; {t._length_}]"
    return {ctypes.c_uint64: "u64", ctypes.c_uint32: "u32", ctypes.c_uint8: "u8", ctypes.c_double: "f64"}[t]
types = {
    name: {
        "type_name": t.type_name(),
        "size": ctypes.sizeof(t),
        "align": ctypes.alignment(t),
        "fields": [[f.rstrip("_") or f, getattr(t, f).offset, getattr(t, f).size, rust(ft)] for f, ft in t._fields_],
    }
    for name, t in wire.TYPES.items()
}
names = ["STATE_FINAL", "TEL_CLAMPED", "TEL_HELD", "TEL_MISSED", "TEL_REJECTED", "TEL_SAFE_STOP",
         "READY", "START", "STOP", "FAULT", "ARMED", "DIVERGED", "FROM_PLANT", "FROM_CONTROLLER", "FROM_SUPERVISOR"]
consts = {n: getattr(wire, n) for n in names}
consts.update({n: getattr(controller, n) for n in ["REF_CHUNK", "REF_RING", "LOOP_BUFFER", "OBSERVER_BUFFER", "HANDSHAKE_TIMEOUT_NS"]})
print(json.dumps({"types": types, "constants": consts}))
"#,
    );
    let py: Value = serde_json::from_str(&out).unwrap();
    for (name, want) in &rust {
        assert_eq!(
            &py["types"][name], want,
            "python/deltaloop/wire.py: {name} differs from the Rust type"
        );
    }
    assert_eq!(
        py["types"].as_object().unwrap().len(),
        rust.len(),
        "{}",
        py["types"]
    );
    assert_eq!(py["constants"], constants);
}

/// The Python `tdc` example runs S1 in lockstep to completion and tracks like the built-in `tdc`
/// (measured: its trace is bit-identical to the built-in's, max-joint RMS 5.805e-6 rad for
/// both); asserted: max-joint RMS within 1 % of the built-in inproc run's, and the run leaves
/// no iceoryx2 resources behind.
#[test]
fn a_python_controller_tracks_s1_in_lockstep_like_the_builtin() {
    let py = python();
    let py = py.to_str().unwrap();
    assert!(
        !py.contains(char::is_whitespace),
        "--controller-cmd splits at whitespace: move the checkout ({py})"
    );
    let tmp = tempfile::tempdir().unwrap();
    let (builtin, ours) = (tmp.path().join("inproc"), tmp.path().join("python"));
    let cmd = format!("{py} examples/python-controller/controller.py");
    let b = common::run(
        "configs/s1-nominal.toml",
        "inproc",
        &builtin,
        &["--law", "tdc"],
    );
    let s = common::run(
        "configs/s1-nominal.toml",
        "lockstep",
        &ours,
        &["--law", "tdc", "--controller-cmd", &cmd],
    );
    let log = std::fs::read_to_string(ours.join("tdc.controller.log")).unwrap_or_default();
    let m = &s["laws"]["tdc"];
    assert_eq!(m["completed"], true, "{m}\ncontroller log:\n{log}");
    assert_eq!(m["lost_ticks"], 0, "{m}");
    let max_rms = |v: &Value| {
        v["laws"]["tdc"]["rms_rad"]
            .as_array()
            .unwrap()
            .iter()
            .map(|x| x.as_f64().unwrap())
            .fold(0.0, f64::max)
    };
    let (want, got) = (max_rms(&b), max_rms(&s));
    assert!(want > 0.0 && want < 1e-4, "built-in inproc RMS {want}");
    assert!(
        (got - want).abs() <= 0.01 * want,
        "Python tdc max-joint RMS {got:e} rad vs built-in {want:e} rad (bound 1 %)\ncontroller log:\n{log}"
    );
    let cfg = std::fs::read_to_string(ours.join("config.toml")).unwrap();
    assert!(cfg.contains("controller.py"), "{cfg}");
    common::assert_clean(&ours, &s);
}

/// A Python controller that meets a service of another payload type (here the run's `state`
/// created with `TorqueMsg`) ends at set-up with exit 3 and one line naming the service and the
/// type it expected.
#[test]
fn a_python_controller_names_a_service_of_another_type() {
    let run_id = format!("pyinterop-{:x}", std::process::id());
    let node = ipc::node("supervisor", &run_id).unwrap();
    let state = node
        .service_builder(&ipc::service_name(&run_id, "state").unwrap())
        .publish_subscribe::<TorqueMsg>()
        .max_publishers(1)
        .max_subscribers(2)
        .max_nodes(4)
        .subscriber_max_buffer_size(ipc::OBSERVER_BUFFER)
        .history_size(0)
        .enable_safe_overflow(true)
        .create()
        .unwrap();
    let tmp = tempfile::tempdir().unwrap();
    let cfg = tmp.path().join("config.toml");
    std::fs::write(
        &cfg,
        "[controller]\nm_bar = 0.03\nkp = 1800.0\nkd = 1800.0\n[loop]\nts_s = 3e-4\n",
    )
    .unwrap();
    let o = run_cmd(
        Command::new(python())
            .arg("examples/python-controller/controller.py")
            .args(["--run-id", &run_id, "--config"])
            .arg(&cfg)
            .args(["--mode", "lockstep", "--law", "tdc"])
            .current_dir(root()),
        "python controller",
    );
    let err = text(&o.stderr);
    assert_eq!(o.status.code(), Some(3), "{err}");
    assert_eq!(err.trim().lines().count(), 1, "{err}");
    for want in [
        format!("deltaloop/{run_id}/state"),
        "IncompatibleTypes".into(),
        "deltaloop::StateMsg/v1".into(),
    ] {
        assert!(err.contains(&want), "no `{want}` in: {err}");
    }
    // The Python process removed its node on the way out.
    drop((state, node));
    let left = common::iceoryx_leftovers(&run_id);
    assert!(left.is_empty(), "left behind: {left:?}");
}
