"""deltaloop from Python: the wire types (`deltaloop.wire`) and two helpers for writing a process
that joins a `deltaloop run`: `deltaloop.Controller` (a controller is one `step`) and
`deltaloop.Plant` (a plant is `start` + `step`)."""

from .wire import ControlMsg, RefSample, StateMsg, TelemetryMsg, TorqueMsg

__all__ = ["Controller", "Plant", "ControlMsg", "RefSample", "StateMsg", "TelemetryMsg", "TorqueMsg"]


def __getattr__(name):
    # The helpers need iceoryx2; the wire types alone do not (imported lazily).
    if name == "Controller":
        from .controller import Controller

        return Controller
    if name == "Plant":
        from .plant import Plant

        return Plant
    raise AttributeError(name)
