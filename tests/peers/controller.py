"""A misbehaving deltaloop controller for tests/e2e/foreign_peers.rs: the `tdc` law of
examples/python-controller on the `deltaloop` helper, plus one kind of misbehaviour chosen by the
first argument (the supervisor's own arguments follow it):

    forge             at tick 10, try to publish on the supervisor's and the plant's control
                      services, then send START, STOP, DIVERGED and FAULT on its own service,
                      claiming to be the supervisor or the plant (with escape codes in the text)
    speak-for-plant   before READY, publish READY and DIVERGED on the plant's control service
    stamp-zero        stamp every reply's t_publish_ns with 0
    twice             send every reply twice, the second with another torque
    raise-at-200      raise an exception in `step` at tick 200

Each attempt prints one line on stderr saying whether it was refused.
"""

import pathlib
import sys

import iceoryx2 as iox2

ROOT = pathlib.Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "examples/python-controller"))

import deltaloop.controller as dc  # noqa: E402
from controller import Tdc  # noqa: E402
from deltaloop import wire  # noqa: E402

MODE = sys.argv[1]


def say(line):
    print(f"evil-controller: {line}", file=sys.stderr, flush=True)


def message(kind, sender, tick=0, text=""):
    m = wire.ControlMsg()
    m.kind, m.from_, m.tick = kind, sender, tick
    b = text.encode()[:160]
    for i, c in enumerate(b):
        m.text[i] = c
    if kind == wire.START:
        m.ticks, m.t0_ns = 5, dc.now_ns()
    return m


def try_publish(ports, what, m):
    """Opens a publisher on `what` and sends `m`; says whether iceoryx2 let it."""
    try:
        svc = ports.pubsub(what, wire.ControlMsg, 1, 3, 64)
        pub = svc.publisher_builder().create()
        pub.send_copy(m)
        say(f"publish on {what}: SENT")
        return pub
    except Exception as e:  # noqa: BLE001 - the refusal is the point
        say(f"publish on {what}: refused ({type(e).__name__})")
        return None


class Evil(dc.Controller):
    def _open_ports_with(self, ports):
        self._ports = ports
        if MODE == "speak-for-plant":
            # Before the plant has its port: take the plant's control service and speak for it.
            self._held = try_publish(ports, "control-plant", message(wire.READY, wire.FROM_PLANT))
            if self._held is not None:
                self._held.send_copy(message(wire.DIVERGED, wire.FROM_PLANT, 3, "forged"))
        super()._open_ports_with(ports)
        if MODE == "twice":
            inner = self.torque

            class Twice:
                def send_copy(self, msg):
                    inner.send_copy(msg)
                    other = wire.TorqueMsg.from_buffer_copy(msg)
                    other.tau = tuple(t + 1.0 for t in msg.tau)
                    inner.send_copy(other)

                def __getattr__(self, name):
                    return getattr(inner, name)

            self.torque = Twice()

    def forge(self):
        try_publish(self._ports, "control", message(wire.STOP, wire.FROM_SUPERVISOR))
        try_publish(self._ports, "control-plant", message(wire.DIVERGED, wire.FROM_PLANT, 3, "x"))
        evil = "\x1b[2J\x1b[31mFORGED\nsecond line"
        for m in [
            message(wire.START, wire.FROM_SUPERVISOR),
            message(wire.STOP, wire.FROM_SUPERVISOR),
            message(wire.DIVERGED, wire.FROM_PLANT, 3, evil),
            message(wire.FAULT, wire.FROM_PLANT, 3, evil),
            message(wire.DIVERGED, wire.FROM_CONTROLLER, 3, evil),
        ]:
            self.control_pub.send_copy(m)
        say("sent START, STOP, DIVERGED and FAULT on its own control service")


def main():
    ctl = Evil(sys.argv[2:], name="evil-controller")
    law = Tdc(ctl.config)
    if MODE == "stamp-zero":
        real = dc.now_ns
        forge = {"next": False}

        def stamped():  # the first clock read after `step` is the reply's publish stamp
            if forge["next"]:
                forge["next"] = False
                return 0
            return real()

        dc.now_ns = stamped

    def step(state, ref):
        if MODE == "forge" and state.tick == 10:
            ctl.forge()
        if MODE == "raise-at-200" and state.tick == 200:
            raise ArithmeticError("the solver did not converge")
        out = law.step(state, ref)
        if MODE == "stamp-zero":
            forge["next"] = True
        return out

    return ctl.run(step)


if __name__ == "__main__":
    iox2.set_log_level_from_env_or(iox2.LogLevel.Error)
    sys.exit(main())
