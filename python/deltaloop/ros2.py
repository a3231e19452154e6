"""deltaloop's ROS 2 topics from Python, over plain DDS (PyPI `cyclonedds`, no ROS install, no rclpy).

`deltaloop run --ros2` publishes a run as ROS 2 messages, and `--controller ros2` hands the control
loop to a ROS 2 node; both are deltaloop's RustDDS side. This module is the other end: the message
types, the QoS of each topic, the topic names and a participant pinned to loopback, for the scripts
in examples/ros2/ (and tested against deltaloop's RustDDS side).

A ROS 2 message is a DDS type `pkg::msg::dds_::Name_`: a final struct, serialized as XCDR1
little endian (encapsulation 00 01 00 00), fields in .msg order. A ROS topic `/a/b` is the DDS
topic `rt/a/b`; every topic here is NoKey. The mapping (.msg → Python field types):
int32 / uint32 / uint8 → int32 / uint32 / uint8, float64 → float64, string → str,
T[] → sequence[T], char[16] → array[uint8, 16] (read back as bytes).

The one difference between distros is rmw_dds_common's Gid: 16 bytes from Iron on (Jazzy), 24 on
Humble. `graph_types(distro)` gives the matching `(Gid, NodeEntitiesInfo, ParticipantEntitiesInfo)`;
the module-level names are Jazzy's.

At the loop's rate, `encode_joint_state` / `decode_joint_state` with `write_raw` / `take_raw` move a
JointState as the same bytes as the generic path, about 5x faster.

Imported on its own (`from deltaloop import ros2`): `import deltaloop` does not need cyclonedds.
"""

import struct
from dataclasses import dataclass, field

from cyclonedds._clayer import ddspy_take, ddspy_write  # the raw-bytes calls behind DataReader.take / DataWriter.write
from cyclonedds.core import InstanceState, SampleState, ViewState
from cyclonedds.domain import Domain, DomainParticipant
from cyclonedds.idl import IdlStruct
from cyclonedds.idl.types import array, float64, int32, sequence, uint8, uint32
from cyclonedds.qos import Policy, Qos
from cyclonedds.util import duration

TS_NS = 300_000  # Ts of the contract (0.3 ms): stamp of tick k = k · TS_NS
JOINTS = ["joint_1", "joint_2", "joint_3"]
FRAME = "base"

# ---- the types (.msg field order; identical in Humble and Jazzy except Gid) ----------------------


@dataclass
class Time(IdlStruct, typename="builtin_interfaces::msg::dds_::Time_"):
    sec: int32 = 0
    nanosec: uint32 = 0


@dataclass
class Duration(IdlStruct, typename="builtin_interfaces::msg::dds_::Duration_"):
    sec: int32 = 0
    nanosec: uint32 = 0


@dataclass
class Header(IdlStruct, typename="std_msgs::msg::dds_::Header_"):
    stamp: Time = field(default_factory=Time)
    frame_id: str = ""


@dataclass
class JointState(IdlStruct, typename="sensor_msgs::msg::dds_::JointState_"):
    header: Header = field(default_factory=Header)
    name: sequence[str] = field(default_factory=list)
    position: sequence[float64] = field(default_factory=list)
    velocity: sequence[float64] = field(default_factory=list)
    effort: sequence[float64] = field(default_factory=list)


@dataclass
class Clock(IdlStruct, typename="rosgraph_msgs::msg::dds_::Clock_"):
    clock: Time = field(default_factory=Time)


@dataclass
class Vector3(IdlStruct, typename="geometry_msgs::msg::dds_::Vector3_"):
    x: float64 = 0.0
    y: float64 = 0.0
    z: float64 = 0.0


@dataclass
class Quaternion(IdlStruct, typename="geometry_msgs::msg::dds_::Quaternion_"):
    x: float64 = 0.0
    y: float64 = 0.0
    z: float64 = 0.0
    w: float64 = 1.0


@dataclass
class Transform(IdlStruct, typename="geometry_msgs::msg::dds_::Transform_"):
    translation: Vector3 = field(default_factory=Vector3)
    rotation: Quaternion = field(default_factory=Quaternion)


@dataclass
class TransformStamped(IdlStruct, typename="geometry_msgs::msg::dds_::TransformStamped_"):
    header: Header = field(default_factory=Header)
    child_frame_id: str = ""
    transform: Transform = field(default_factory=Transform)


@dataclass
class TFMessage(IdlStruct, typename="tf2_msgs::msg::dds_::TFMessage_"):
    transforms: sequence[TransformStamped] = field(default_factory=list)


@dataclass
class KeyValue(IdlStruct, typename="diagnostic_msgs::msg::dds_::KeyValue_"):
    key: str = ""
    value: str = ""


@dataclass
class DiagnosticStatus(IdlStruct, typename="diagnostic_msgs::msg::dds_::DiagnosticStatus_"):
    level: uint8 = 0  # OK 0, WARN 1, ERROR 2, STALE 3
    name: str = ""
    message: str = ""
    hardware_id: str = ""
    values: sequence[KeyValue] = field(default_factory=list)


@dataclass
class DiagnosticArray(IdlStruct, typename="diagnostic_msgs::msg::dds_::DiagnosticArray_"):
    header: Header = field(default_factory=Header)
    status: sequence[DiagnosticStatus] = field(default_factory=list)


@dataclass
class Log(IdlStruct, typename="rcl_interfaces::msg::dds_::Log_"):
    stamp: Time = field(default_factory=Time)
    level: uint8 = 0  # DEBUG 10, INFO 20, WARN 30, ERROR 40, FATAL 50
    name: str = ""
    msg: str = ""
    file: str = ""
    function: str = ""
    line: uint32 = 0


@dataclass
class JointTrajectoryPoint(IdlStruct, typename="trajectory_msgs::msg::dds_::JointTrajectoryPoint_"):
    positions: sequence[float64] = field(default_factory=list)
    velocities: sequence[float64] = field(default_factory=list)
    accelerations: sequence[float64] = field(default_factory=list)
    effort: sequence[float64] = field(default_factory=list)
    time_from_start: Duration = field(default_factory=Duration)


@dataclass
class JointTrajectory(IdlStruct, typename="trajectory_msgs::msg::dds_::JointTrajectory_"):
    header: Header = field(default_factory=Header)
    joint_names: sequence[str] = field(default_factory=list)
    points: sequence[JointTrajectoryPoint] = field(default_factory=list)


def _make_graph_types(n):
    """rmw_dds_common's Gid / NodeEntitiesInfo / ParticipantEntitiesInfo with an `n`-byte Gid."""

    @dataclass
    class Gid(IdlStruct, typename="rmw_dds_common::msg::dds_::Gid_"):
        data: array[uint8, n] = field(default_factory=lambda: bytes(n))

    @dataclass
    class NodeEntitiesInfo(IdlStruct, typename="rmw_dds_common::msg::dds_::NodeEntitiesInfo_"):
        node_namespace: str = ""
        node_name: str = ""
        reader_gid_seq: sequence[Gid] = field(default_factory=list)
        writer_gid_seq: sequence[Gid] = field(default_factory=list)

    @dataclass
    class ParticipantEntitiesInfo(IdlStruct, typename="rmw_dds_common::msg::dds_::ParticipantEntitiesInfo_"):
        gid: Gid = field(default_factory=Gid)
        node_entities_info_seq: sequence[NodeEntitiesInfo] = field(default_factory=list)

    return Gid, NodeEntitiesInfo, ParticipantEntitiesInfo


GID_BYTES = {"jazzy": 16, "humble": 24}
_GRAPH_TYPES = {d: _make_graph_types(n) for d, n in GID_BYTES.items()}


def graph_types(distro: str = "jazzy"):
    """`(Gid, NodeEntitiesInfo, ParticipantEntitiesInfo)` of `distro`: "jazzy" (Iron and later,
    16-byte Gid) or "humble" (24-byte Gid)."""
    try:
        return _GRAPH_TYPES[distro]
    except KeyError:
        raise ValueError(f"unknown distro {distro!r} (jazzy or humble)") from None


Gid, NodeEntitiesInfo, ParticipantEntitiesInfo = _GRAPH_TYPES["jazzy"]
GidHumble, NodeEntitiesInfoHumble, ParticipantEntitiesInfoHumble = _GRAPH_TYPES["humble"]

# ---- QoS of each topic (the writer's; a reader asks for the same) --------------------------------

_RELIABLE = Policy.Reliability.Reliable(duration(milliseconds=100))
QOS_JOINT = Qos(_RELIABLE, Policy.Durability.Volatile, Policy.History.KeepLast(100))  # joint_states, reference
QOS_TRAJECTORY = Qos(_RELIABLE, Policy.Durability.TransientLocal, Policy.History.KeepLast(1))
QOS_TF = Qos(_RELIABLE, Policy.Durability.Volatile, Policy.History.KeepLast(100))
QOS_CLOCK = Qos(Policy.Reliability.BestEffort, Policy.Durability.Volatile, Policy.History.KeepLast(1))
QOS_DIAGNOSTICS = Qos(_RELIABLE, Policy.Durability.Volatile, Policy.History.KeepLast(10))
QOS_ROSOUT = Qos(_RELIABLE, Policy.Durability.TransientLocal, Policy.History.KeepLast(1000))
QOS_ROBOT = Qos(_RELIABLE, Policy.Durability.Volatile, Policy.History.KeepLast(10))  # robot_joint_states / _commands
QOS_DISCOVERY = Qos(_RELIABLE, Policy.Durability.TransientLocal, Policy.History.KeepLast(1))  # ros_discovery_info

# ---- names ---------------------------------------------------------------------------------------

TOPIC_TF, TOPIC_CLOCK, TOPIC_DIAGNOSTICS, TOPIC_ROSOUT = "rt/tf", "rt/clock", "rt/diagnostics", "rt/rosout"
TOPIC_ROBOT_STATES, TOPIC_ROBOT_COMMANDS = "rt/robot_joint_states", "rt/robot_joint_commands"
TOPIC_DISCOVERY = "ros_discovery_info"


def ros_name(law: str) -> str:
    """A law as a ROS name component: `tdc-is-sta` → `tdc_is_sta` (ROS names allow no `-`)."""
    return law.replace("-", "_")


def topic_prefix(namespace: str, law: str) -> str:
    """The DDS name prefix of one law's topics: `rt/<namespace>/<law with _>`."""
    return f"rt/{namespace}/{ros_name(law)}"


def stamp(k: int, ts_ns: int = TS_NS) -> Time:
    """The stamp of tick k: k · Ts."""
    sec, nanosec = divmod(k * ts_ns, 1_000_000_000)
    return Time(sec, nanosec)


def stamp_ns(t) -> int:
    """A Time (or Duration) in ns."""
    return t.sec * 1_000_000_000 + t.nanosec


# ---- JointState at the speed of the loop --------------------------------------------------------
# cyclonedds's generic (de)serializer takes ~20 µs per JointState here, and a Python round trip
# through it about 190 µs against 28 µs with raw bytes. These write the very bytes of
# `JointState.serialize()` (checked in the tests of examples/ros2) with `struct`, and write/take
# them through cyclonedds's raw calls (internal to cyclonedds, hence the exact pin 11.0.1).

CDR_LE = b"\x00\x01\x00\x00"  # encapsulation: XCDR1 (plain CDR), little endian, no options
_II, _I = struct.Struct("<iI"), struct.Struct("<I")
_ANY = SampleState.Any | ViewState.Any | InstanceState.Any


def _put_str(out: bytearray, s: str) -> None:
    out += b"\0" * (-len(out) % 4)
    b = s.encode()
    out += _I.pack(len(b) + 1) + b + b"\0"


def _put_f64s(out: bytearray, xs) -> None:
    out += b"\0" * (-len(out) % 4)
    out += _I.pack(len(xs))
    if xs:
        out += b"\0" * (-len(out) % 8)
        out += struct.pack(f"<{len(xs)}d", *xs)


def encode_joint_state(sec: int, nanosec: int, frame_id: str, name, position, velocity, effort) -> bytes:
    """The CDR_LE bytes of a JointState, encapsulation included (alignment counts from after it)."""
    out = bytearray(_II.pack(sec, nanosec))
    _put_str(out, frame_id)
    out += b"\0" * (-len(out) % 4)
    out += _I.pack(len(name))
    for n in name:
        _put_str(out, n)
    for xs in (position, velocity, effort):
        _put_f64s(out, xs)
    return CDR_LE + bytes(out)


def decode_joint_state(data: bytes) -> JointState:
    """A JointState from its serialized bytes (any encapsulation; CDR_LE the fast way)."""
    if data[:2] != CDR_LE[:2]:
        return JointState.deserialize(data)
    b = memoryview(data)[4:]
    sec, nanosec = _II.unpack_from(b, 0)
    (n,) = _I.unpack_from(b, 8)
    frame_id = str(b[12 : 12 + n - 1], "utf-8")
    o = 12 + n
    o += -o % 4
    (count,) = _I.unpack_from(b, o)
    o += 4
    name = []
    for _ in range(count):
        o += -o % 4
        (n,) = _I.unpack_from(b, o)
        name.append(str(b[o + 4 : o + 3 + n], "utf-8"))
        o += 4 + n
    seqs = []
    for _ in range(3):
        o += -o % 4
        (count,) = _I.unpack_from(b, o)
        o += 4
        if count:
            o += -o % 8
            seqs.append(list(struct.unpack_from(f"<{count}d", b, o)))
            o += 8 * count
        else:
            seqs.append([])
    return JointState(Header(Time(sec, nanosec), frame_id), name, *seqs)


def write_raw(writer, data: bytes) -> None:
    """Writes one serialized sample (as DataWriter.write does after serializing)."""
    data = data + b"\0" * (-len(data) % 4)
    ret = ddspy_write(writer._ref, data)
    if ret < 0:
        raise RuntimeError(f"dds_write failed: {ret}")


def take_raw(reader, n: int) -> list:
    """Takes up to `n` samples as their serialized bytes; samples without data (a writer gone)
    are dropped."""
    ret = ddspy_take(reader._ref, _ANY, n)
    if isinstance(ret, int):
        raise RuntimeError(f"dds_take failed: {ret}")
    return [data for data, info in ret if info.valid_data]


# ---- loopback ------------------------------------------------------------------------------------


def loopback_xml() -> str:
    """Cyclone DDS config that keeps all traffic on loopback: interface lo, no multicast (discovery
    by unicast to 127.0.0.1's well-known ports), participant index auto (below 20, so RustDDS's
    localhost probes find it). Also usable as CYCLONEDDS_URI for other Cyclone tools."""
    return (
        '<CycloneDDS xmlns="https://cdds.io/config"><Domain Id="any">'
        '<General><Interfaces><NetworkInterface name="lo" multicast="false"/></Interfaces>'
        "<AllowMulticast>false</AllowMulticast></General>"
        "<Discovery><ParticipantIndex>auto</ParticipantIndex>"
        "<MaxAutoParticipantIndex>20</MaxAutoParticipantIndex>"
        '<Peers><Peer address="127.0.0.1"/></Peers></Discovery>'
        "</Domain></CycloneDDS>"
    )


_domains = {}  # domain id → Domain: created once per process and kept alive


def participant(domain: int) -> DomainParticipant:
    """A DomainParticipant on DDS domain `domain`, pinned to loopback whatever CYCLONEDDS_URI says
    (the domain is created from `loopback_xml()` before any participant joins it)."""
    if domain not in _domains:
        _domains[domain] = Domain(domain, config=loopback_xml())
    dp = DomainParticipant(domain)
    dp.loopback_domain = _domains[domain]  # the participant keeps its Domain alive too
    return dp
