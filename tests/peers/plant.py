"""A misbehaving deltaloop plant for tests/e2e/foreign_peers.rs: a free rotor per joint (0.03 kg m²)
with gravity held by the start torque, on the `deltaloop` helper, plus one misbehaviour chosen
by the first argument (the supervisor's own arguments follow it):

    idle          never joins: creates no port, sleeps until it is stopped
    mute-after N  stops sending telemetry after tick N
    quit-after N  exits with status 0 at tick N, without a final state
    echo-state    publishes each state a second time once its reply has arrived
"""

import sys
import time

MODE = sys.argv[1]
if MODE == "idle":
    time.sleep(120)
    sys.exit(0)

from deltaloop import Plant  # noqa: E402

AFTER = int(sys.argv[2]) if MODE in ("mute-after", "quit-after") else None
ARGS = sys.argv[3:] if AFTER is not None else sys.argv[2:]
INERTIA = 0.03


class Odd(Plant):
    def _open_ports_with(self, ports):
        super()._open_ports_with(ports)
        if MODE == "mute-after":
            inner, plant = self.telemetry, self

            class Mute:
                def send_copy(self, tel):
                    if tel.tick <= AFTER:
                        inner.send_copy(tel)

                def __getattr__(self, name):
                    return getattr(inner, name)

            self.telemetry = Mute()

    def _wait_torque(self, *args):
        got = super()._wait_torque(*args)
        if MODE == "echo-state" and got is not None:
            self.state.send_copy(self._state)
            self.state_ready.notify()
        return got


plant = Odd(ARGS, name="odd-plant")
q, qd = [0.0] * 3, [0.0] * 3


def start(q0):
    q[:] = q0
    return q, qd, (0.0, 0.0, 0.0)


def step(tau, dt):
    if MODE == "quit-after" and plant.tick == AFTER:
        sys.exit(0)
    for i in range(3):
        qd[i] += tau[i] / INERTIA * dt
        q[i] += qd[i] * dt
    return q, qd, tau


sys.exit(plant.run(start, step))
