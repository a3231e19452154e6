//! A controller written in Python joins a deltaloop run: the `deltaloop` Python package
//! (`python/`: ctypes wire types and a controller helper over the iceoryx2 Python bindings) and the
//! `tdc` law of `examples/python-controller/controller.py`, run with `--controller-cmd`.
//!
//! The tests need Python ≥ 3.11 with its `venv` module; they set up a virtual environment in
//! `target/python-venv` (once, or again when it lacks the pinned iceoryx2 or holds an older copy
//! of `python/`), installing `python/requirements.txt` and `python/` with pip (network access to
//! PyPI the first time). Without Python they fail and say what to install; they never pass
//! silently.

use crate::common;

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
    let rust: serde_json::Map<String, Value> = common::wire_types!(layout)
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
        "TEL_STAMP_REPLACED": wire::TEL_STAMP_REPLACED,
        "WIRE_VERSION": wire::WIRE_VERSION,
        "WIRE_ATTRIBUTE": wire::WIRE_ATTRIBUTE,
        "READY": ControlKind::Ready as u32,
        "START": ControlKind::Start as u32,
        "STOP": ControlKind::Stop as u32,
        "FAULT": ControlKind::Fault as u32,
        "ARMED": ControlKind::Armed as u32,
        "DIVERGED": ControlKind::Diverged as u32,
        "STOPPED": ControlKind::Stopped as u32,
        "OVERRUN": ControlKind::Overrun as u32,
        "PLANT_ERROR": ControlKind::PlantError as u32,
        "CONTROLLER_ERROR": ControlKind::ControllerError as u32,
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
names = ["WIRE_VERSION", "WIRE_ATTRIBUTE", "STATE_FINAL", "TEL_CLAMPED", "TEL_HELD", "TEL_MISSED", "TEL_REJECTED", "TEL_SAFE_STOP", "TEL_STAMP_REPLACED",
         "READY", "START", "STOP", "FAULT", "ARMED", "DIVERGED", "STOPPED", "OVERRUN", "PLANT_ERROR", "CONTROLLER_ERROR", "FROM_PLANT", "FROM_CONTROLLER", "FROM_SUPERVISOR"]
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
/// A state message of another layout under the current name: StateMsg/v2, 16 bytes shorter.
#[derive(Debug, Clone, Copy, ZeroCopySend)]
#[repr(C)]
#[type_name("deltaloop::StateMsg/v2")]
struct ShorterState {
    bytes: [u64; 19],
}

/// Creates the run's `state` service with payload `T`, as a supervisor of another wire version
/// would, starts the example Python controller against it and returns its exit code and stderr.
fn python_controller_against_state<T: std::fmt::Debug + ZeroCopySend>(tag: &str) -> (i32, String) {
    let run_id = format!("pyinterop-{tag}-{:x}", std::process::id());
    let node = ipc::node("supervisor", &run_id).unwrap();
    let state = node
        .service_builder(&ipc::service_name(&run_id, "state").unwrap())
        .publish_subscribe::<T>()
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
    // The Python process removed its node on the way out.
    drop((state, node));
    let left = common::iceoryx_leftovers(&run_id);
    assert!(left.is_empty(), "left behind: {left:?}");
    (o.status.code().unwrap_or(-1), err)
}

/// A peer of another wire version gets one line naming the service, what the run carries and what
/// it expected (type name, size, alignment), and exit code 3 (set-up failed).
#[test]
fn a_python_controller_names_the_expected_and_found_types() {
    let state = format!(
        "deltaloop::StateMsg/v2 ({} B, align 8)",
        size_of::<StateMsg>()
    );
    let cases = [
        (
            python_controller_against_state::<TorqueMsg>("type"),
            format!(
                "deltaloop::TorqueMsg/v2 ({} B, align 8)",
                size_of::<TorqueMsg>()
            ),
        ),
        (
            python_controller_against_state::<ShorterState>("size"),
            format!(
                "deltaloop::StateMsg/v2 ({} B, align 8)",
                size_of::<ShorterState>()
            ),
        ),
    ];
    for ((code, err), carried) in cases {
        assert_eq!(code, 3, "{err}");
        assert_eq!(err.trim().lines().count(), 1, "{err}");
        for want in [
            "/state: IncompatibleTypes".to_string(),
            format!("the run carries {carried}"),
            format!("expects {state} on iceoryx2 0.10.0"),
        ] {
            assert!(err.contains(&want), "no `{want}` in: {err}");
        }
    }
}

/// The C ABI from a second language: the Python `tdc` law served through `ctypes` by the C
/// library (examples/c-controller/ctypes_tdc.py) writes the built-in `tdc`'s trace byte for byte.
#[test]
fn the_c_library_serves_a_python_law_through_ctypes_byte_for_byte() {
    let tmp = tempfile::tempdir().unwrap();
    let lib = common::peer_lib_dir().join("libdeltaloop_peer.so");
    let cmd = format!(
        "{} examples/c-controller/ctypes_tdc.py {}",
        python().display(),
        lib.display()
    );
    let (ours, builtin) = (tmp.path().join("ctypes"), tmp.path().join("builtin"));
    let s = common::run(
        "configs/s1-nominal.toml",
        "lockstep",
        &ours,
        &["--law", "tdc", "--controller-cmd", &cmd],
    );
    common::run(
        "configs/s1-nominal.toml",
        "inproc",
        &builtin,
        &["--law", "tdc"],
    );
    assert!(
        std::fs::read(ours.join("trace.csv")).unwrap()
            == std::fs::read(builtin.join("trace.csv")).unwrap(),
        "the ctypes controller's trace.csv differs from the built-in tdc's"
    );
    common::assert_clean(&ours, &s);
}

/// Regression: a peer written for the single shared `control` service (wire version 2) failed
/// with iceoryx2's `DoesNotSupportRequestedAmountOfPublishers` and no word of why; the run's
/// error now says the control services are one per sender, with the wire version.
#[test]
fn regression_a_peer_of_the_single_control_service_is_told_they_are_per_sender() {
    let tmp = tempfile::tempdir().unwrap();
    let script = tmp.path().join("old_controller.py");
    std::fs::write(
        &script,
        r#"
import ctypes, sys
import iceoryx2 as iox2
from deltaloop import wire
from deltaloop.services import guest_config
run_id = sys.argv[sys.argv.index("--run-id") + 1]
node = iox2.NodeBuilder.new().config(guest_config()).create(iox2.ServiceType.Ipc)
try:
    (node.service_builder(iox2.ServiceName.new(f"deltaloop/{run_id}/control"))
        .publish_subscribe(wire.ControlMsg).max_publishers(3).max_subscribers(3).max_nodes(4)
        .subscriber_max_buffer_size(64).history_size(0).enable_safe_overflow(True).open())
except Exception as e:
    print(f"cannot open control: {e!r}", file=sys.stderr)
    sys.exit(3)
"#,
    )
    .unwrap();
    let cmd = format!("{} {}", python().display(), script.display());
    let out = tmp.path().join("run");
    let o = common::run_output(
        "configs/s1-nominal.toml",
        "lockstep",
        &out,
        &["--law", "tdc", "--controller-cmd", &cmd],
    );
    assert!(!o.status.success());
    let line = common::one_line_error(&o);
    for want in [
        "DoesNotSupportRequestedAmountOfPublishers",
        "wire version 3",
        "one per sender",
        "control-controller",
    ] {
        assert!(line.contains(want), "no `{want}` in: {line}");
    }
}

/// `examples/python-watcher/watch.py` attaches to a live run through the spare slots, follows it
/// to its last tick, and the run completes with nothing lost, as if nobody had watched.
#[test]
fn a_python_watcher_follows_a_live_run_without_disturbing_it() {
    let py = python();
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("run");
    let run = Command::new(env!("CARGO_BIN_EXE_deltaloop"))
        .args(["run", "configs/s1-nominal.toml", "--mode", "lockstep"])
        .args(["--law", "tdc", "--hold-s", "10", "--out"])
        .arg(&out)
        .current_dir(root())
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    // Run ids start with the supervisor's pid in hex.
    let watch = run_cmd(
        Command::new(py)
            .arg("examples/python-watcher/watch.py")
            .arg(format!("{:x}-", run.id()))
            .args(["--wait", "30"])
            .current_dir(root()),
        "watcher",
    );
    let run_out = run.wait_with_output().unwrap();
    assert!(run_out.status.success(), "{}", text(&run_out.stderr));
    let said = text(&watch.stdout);
    assert!(watch.status.success(), "{said}{}", text(&watch.stderr));
    let summary = common::summary(&out);
    common::assert_complete_and_kept(&summary, &out, "tdc");
    let run_id = summary["run_ids"]["tdc"].as_str().unwrap();
    assert!(
        said.starts_with(&format!("watching run {run_id}\n")),
        "{said}"
    );
    let last = said.lines().last().unwrap();
    let ticks = summary["laws"]["tdc"]["ticks"].as_u64().unwrap();
    let (watched, last_tick): (u64, u64) = {
        let n: Vec<u64> = last
            .split(|c: char| !c.is_ascii_digit())
            .filter_map(|w| w.parse().ok())
            .collect();
        (n[n.len() - 3], n[n.len() - 2])
    };
    assert!(last.starts_with(&format!("run {run_id} is over")), "{said}");
    assert_eq!(
        last_tick, ticks,
        "the watcher saw the run's last tick: {last}"
    );
    assert!(watched > 0 && watched <= ticks + 1, "{last}");
}
