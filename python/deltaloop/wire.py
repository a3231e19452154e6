"""ctypes mirrors of deltaloop's wire types (protocol/wire/src/lib.rs).

Field order, sizes and alignments are those of the Rust `#[repr(C)]` structs; each type's
`type_name()` is its iceoryx2 type name, which iceoryx2 compares (with size and alignment) when a
service is opened. `tests/e2e/python_interop.rs` checks all of it against the Rust types.
"""

import ctypes

Vec3 = ctypes.c_double * 3

# StateMsg.flags
# The run's wire version and the service attribute that carries it (wire.rs WIRE_VERSION):
# every publish-subscribe service of a run holds it; a peer checks it when it opens them.
WIRE_VERSION = 3
WIRE_ATTRIBUTE = "deltaloop-wire"

STATE_FINAL = 1

# TelemetryMsg.flags
TEL_CLAMPED = 1
TEL_HELD = 2
TEL_MISSED = 4
TEL_REJECTED = 8
TEL_SAFE_STOP = 16
TEL_STAMP_REPLACED = 32  # the reply's t_publish_ns could not be true: the plant used its receive time

# ControlMsg.kind (kind 5 is unused)
READY = 1
START = 2
STOP = 3
FAULT = 4
ARMED = 6
DIVERGED = 7
STOPPED = 8
OVERRUN = 9
PLANT_ERROR = 10  # the plant's own physics failed at `tick`; `text` quotes the error
CONTROLLER_ERROR = 11  # the controller's step failed at `tick`; the plant stops at once
REPLIES_LOST = 12  # the replies to ticks `tick`..=`ticks` may have been lost on the link (a bridge says it)
REPLIES_REFUSED = 13  # at the end: the controller's own transport refused `ticks` replies (`text`: each cause)

# ControlMsg.from
FROM_PLANT = 1
FROM_CONTROLLER = 2
FROM_SUPERVISOR = 3

# The control service each sender publishes on (one publisher each; docs/protocol.md §3, §5).
CONTROL_SERVICE = {FROM_SUPERVISOR: "control", FROM_PLANT: "control-plant", FROM_CONTROLLER: "control-controller"}


class StateMsg(ctypes.Structure):
    """Plant -> controller (and supervisor), once per tick."""

    _fields_ = [
        ("tick", ctypes.c_uint64),
        ("flags", ctypes.c_uint32),
        ("_pad", ctypes.c_uint32),
        ("q", Vec3),
        ("qd", Vec3),
        ("tau_applied", Vec3),
        ("q_true", Vec3),
        ("qd_true", Vec3),
        ("t_deadline_ns", ctypes.c_uint64),
        ("t_wake_ns", ctypes.c_uint64),
        ("t_publish_ns", ctypes.c_uint64),
        # Polls `torque` until then before blocking; 0: always notify (docs/protocol.md §6.1).
        ("t_poll_until_ns", ctypes.c_uint64),
    ]

    @staticmethod
    def type_name() -> str:
        return "deltaloop::StateMsg/v2"


class TorqueMsg(ctypes.Structure):
    """Controller -> plant (and supervisor): the answer to one state."""

    _fields_ = [
        ("tick", ctypes.c_uint64),
        ("skipped", ctypes.c_uint64),
        ("tau", Vec3),
        ("s", Vec3),
        ("n_hat", Vec3),
        ("u", Vec3),
        ("t_state_rx_ns", ctypes.c_uint64),
        ("t_publish_ns", ctypes.c_uint64),
        # Polls `state` until then before blocking; 0: always notify (docs/protocol.md §6.1).
        ("t_poll_until_ns", ctypes.c_uint64),
    ]

    @staticmethod
    def type_name() -> str:
        return "deltaloop::TorqueMsg/v2"


class TelemetryMsg(ctypes.Structure):
    """Plant -> supervisor after each tick."""

    _fields_ = [
        ("tick", ctypes.c_uint64),
        ("flags", ctypes.c_uint32),
        ("_pad", ctypes.c_uint32),
        ("t_deadline_ns", ctypes.c_uint64),
        ("t_wake_ns", ctypes.c_uint64),
        ("t_state_pub_ns", ctypes.c_uint64),
        ("t_torque_rx_ns", ctypes.c_uint64),
        ("late_dropped", ctypes.c_uint64),
        ("misses", ctypes.c_uint64),
        ("arrival_ns", ctypes.c_uint64),
    ]

    @staticmethod
    def type_name() -> str:
        return "deltaloop::TelemetryMsg/v2"


class ControlMsg(ctypes.Structure):
    """Run control: handshake, start, stop, faults."""

    _fields_ = [
        ("kind", ctypes.c_uint32),
        ("from_", ctypes.c_uint32),  # `from` in Rust (a Python keyword)
        ("tick", ctypes.c_uint64),
        ("ticks", ctypes.c_uint64),
        ("q0", Vec3),
        ("t0_ns", ctypes.c_uint64),
        ("text", ctypes.c_uint8 * 160),
    ]

    @staticmethod
    def type_name() -> str:
        return "deltaloop::ControlMsg/v1"

    def text_str(self) -> str:
        """The text field (FAULT / DIVERGED / STOPPED), NUL padding removed. Another process
        wrote it: escape it before showing it on a terminal."""
        return bytes(self.text).split(b"\0", 1)[0].decode("utf-8", "replace")


class RefSample(ctypes.Structure):
    """One row of the joint reference; travels as a slice `[RefSample]` (chunks)."""

    _fields_ = [
        ("tick", ctypes.c_uint64),
        ("q", Vec3),
        ("qd", Vec3),
        ("qdd", Vec3),
    ]

    @staticmethod
    def type_name() -> str:
        return "deltaloop::RefSample/v2"


# Every wire type, by its Rust name (the layout test walks this).
TYPES = {
    "StateMsg": StateMsg,
    "TorqueMsg": TorqueMsg,
    "TelemetryMsg": TelemetryMsg,
    "ControlMsg": ControlMsg,
    "RefSample": RefSample,
}
