"""deltaloop from Python: the wire types (`deltaloop.wire`) and a controller helper
(`deltaloop.Controller`) for writing a controller process that joins a `deltaloop run`."""

from .wire import ControlMsg, RefSample, StateMsg, TelemetryMsg, TorqueMsg

__all__ = ["Controller", "ControlMsg", "RefSample", "StateMsg", "TelemetryMsg", "TorqueMsg"]


def __getattr__(name):
    # The helper needs iceoryx2; the wire types alone do not (imported lazily).
    if name == "Controller":
        from .controller import Controller

        return Controller
    raise AttributeError(name)
