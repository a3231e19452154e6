"""What a live deltaloop service carries, for error messages that say expected and found.

iceoryx2's Python bindings (0.10.0) expose a service's static configuration only as text (the
Rust `Debug` form of `ServiceDetails`); this module reads the payload type and the iceoryx2 version
out of it. Anything it cannot read is reported as unknown, never guessed.
"""

import os
import ctypes
import re

import iceoryx2 as iox2

from . import wire

# The iceoryx2 of deltaloop's Cargo.lock (docs/protocol.md §1).
ICEORYX2_VERSION = "0.10.0"

_PAYLOAD = re.compile(
    r'payload: TypeDetail \{\s*variant: (\w+),\s*type_name: StaticString<\d+> '
    r'\{ len: \d+, data: "([^"]*)" \},\s*size: (\d+),\s*alignment: (\d+)'
)
_VERSION = re.compile(r"iceoryx2_version: PackageVersion \{\s*major: (\d+),\s*minor: (\d+),\s*patch: (\d+)")

# What a failed service open means here (iceoryx2's error names).
OPEN_HINTS = {
    "IncompatibleTypes": "another wire version or layout",
    "VersionMismatch": "the run uses another iceoryx2 version",
    "DoesNotExist": "no such service: the run is gone, or the run id is wrong",
    "DoesNotSupportRequestedAmountOfPublishers": (
        "the run's control services are one per sender, each with one publisher: "
        "publish on control-plant or control-controller, read control (docs/protocol.md §3)"
    ),
}


def describe(t) -> str:
    """A ctypes wire type (or iceoryx2.Slice of one) as "[slices of ]NAME (SIZE B, align A)"."""
    elem = t.__args__[0] if hasattr(t, "__args__") else t  # Slice[RefSample] -> RefSample
    slices = "slices of " if elem is not t else ""
    return f"{slices}{elem.type_name()} ({ctypes.sizeof(elem)} B, align {ctypes.alignment(elem)})"


def carried(name: str) -> str:
    """What the live publish-subscribe service `name` carries, in `describe`'s form, with its
    iceoryx2 version when it is not ours; "unknown" when the details cannot be read."""
    try:
        d = str(
            iox2.Service.details(
                iox2.ServiceName.new(name),
                iox2.config.default(),
                iox2.MessagingPattern.PublishSubscribe,
                iox2.ServiceType.Ipc,
            )
        )
    except Exception:  # noqa: BLE001 - only for a message; the open error is what matters
        return "unknown"
    p, v = _PAYLOAD.search(d), _VERSION.search(d)
    if not p:
        return "unknown"
    variant, tname, size, align = p.groups()
    what = f"{'slices of ' if variant == 'Dynamic' else ''}{tname} ({size} B, align {align})"
    if v and ".".join(v.groups()) != ICEORYX2_VERSION:
        what += f" on iceoryx2 {'.'.join(v.groups())}"
    return what


def open_error(name: str, t, e: Exception, who: str) -> str:
    """The one-line message for a publish-subscribe service `name` that would not open with type
    `t`: the iceoryx2 error, what the run's service carries and what `who` expected."""
    kind = e.args[0] if e.args else repr(e)
    hint = OPEN_HINTS.get(kind, "see iceoryx2")
    return (
        f"cannot open service {name}: {kind} ({hint}): the run carries {carried(name)}, "
        f"this {who} expects {describe(t)} on iceoryx2 {ICEORYX2_VERSION}"
    )


def check_wire_version(name: str, svc) -> None:
    """Refuses a service whose run speaks another wire version than this package (or none)."""
    values = svc.attributes.key_values(iox2.AttributeKey.new(wire.WIRE_ATTRIBUTE))
    found = [v.to_string() for v in values]
    if found != [str(wire.WIRE_VERSION)]:
        raise SetupError(
            f"cannot open service {name}: the run speaks deltaloop wire version "
            f"{', '.join(found) or 'none'}, this package speaks {wire.WIRE_VERSION} (docs/protocol.md §2)"
        )


class SetupError(Exception):
    """A node or service of the run could not be opened; the message is one line."""


def guest_config():
    """iceoryx2's default configuration as deltaloop's processes use it: no silent clean-up of
    dead nodes (the supervisor owns the run's resources)."""
    cfg = iox2.config.default()
    cfg.global_cfg.node.cleanup_dead_nodes_on_creation = False
    cfg.global_cfg.node.cleanup_dead_nodes_on_destruction = False
    cfg.global_cfg.service.cleanup_dead_nodes_on_open = False
    own = own_root()
    if own is not None:
        cfg.global_cfg.root_path = iox2.Path.new(own[0])
        cfg.global_cfg.prefix = iox2.FileName.new(own[1])
    return cfg


def own_root():
    """The iceoryx2 root directory and shared-memory prefix that `DELTALOOP_IOX2_ROOT` asks for
    (None: iceoryx2's defaults), exactly as `ipc::own_root` in Rust derives them: the directory
    with a trailing `/`, and `iox2_<FNV-1a 32 of it, hex>_`."""
    v = os.environ.get("DELTALOOP_IOX2_ROOT")
    if not v or not v.startswith("/") or len(v) > 200 or "\0" in v:
        return None
    root = v if v.endswith("/") else v + "/"
    h = 0x811C9DC5
    for b in root.encode():
        h = ((h ^ b) * 0x01000193) & 0xFFFFFFFF
    return root, f"iox2_{h:08x}_"


class RunPorts:
    """Opens the services of one run for one role (`plant`, `controller`) with the settings of
    protocol/transport/src/ipc.rs; every failure is a SetupError naming what and why."""

    def __init__(self, role: str, run_id: str):
        self.role, self.run_id = role, run_id
        iox2.set_log_level_from_env_or(iox2.LogLevel.Error)
        name = f"deltaloop-{role}-{run_id}"
        try:
            self.node = (
                iox2.NodeBuilder.new()
                .name(iox2.NodeName.new(name))
                .config(guest_config())
                .signal_handling_mode(iox2.SignalHandlingMode.Disabled)
                .create(iox2.ServiceType.Ipc)
            )
        except Exception as e:  # noqa: BLE001 - reported as one line
            raise SetupError(f"cannot create the iceoryx2 node {name}: {e!r}") from None

    def name(self, what: str) -> str:
        return f"deltaloop/{self.run_id}/{what}"

    def pubsub(self, what, t, publishers, subscribers, buffer, borrowed=None):
        """Opens a publish-subscribe service the supervisor created."""
        name = self.name(what)
        b = (
            self.node.service_builder(iox2.ServiceName.new(name))
            .publish_subscribe(t)
            .max_publishers(publishers)
            .max_subscribers(subscribers)
            .max_nodes(4)
            .subscriber_max_buffer_size(buffer)
            .history_size(0)
            .enable_safe_overflow(True)
        )
        if borrowed is not None:
            b = b.subscriber_max_borrowed_samples(borrowed)
        try:
            svc = b.open()
        except Exception as e:  # noqa: BLE001 - reported as one line
            raise SetupError(open_error(name, t, e, self.role)) from None
        check_wire_version(name, svc)
        return svc

    def control(self, me):
        """Run control for sender `me` (wire.FROM_PLANT / FROM_CONTROLLER): a publisher on its own
        control service (one publisher slot: it fails if another process holds it), a subscriber
        on the supervisor's `control`, which only the supervisor can publish on."""
        own = self.pubsub(wire.CONTROL_SERVICE[me], wire.ControlMsg, 1, 3, 64)
        sup = self.pubsub(wire.CONTROL_SERVICE[wire.FROM_SUPERVISOR], wire.ControlMsg, 1, 3, 64)
        name = self.name(wire.CONTROL_SERVICE[me])
        try:
            pub = own.publisher_builder().create()
        except Exception as e:  # noqa: BLE001 - reported as one line
            raise SetupError(f"cannot publish on {name} ({e!r}): another process holds its only publisher slot") from None
        return pub, sup.subscriber_builder().create()

    def event(self, what):
        """Opens (or creates: whichever of plant and controller comes first) a wake-up event."""
        name = self.name(what)
        try:
            return (
                self.node.service_builder(iox2.ServiceName.new(name))
                .event()
                .max_notifiers(2)
                .max_listeners(2)
                .max_nodes(4)
                .open_or_create()
            )
        except Exception as e:  # noqa: BLE001 - reported as one line
            raise SetupError(f"cannot open event {name} ({e!r}) on iceoryx2 {ICEORYX2_VERSION}") from None
