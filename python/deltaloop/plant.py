"""A deltaloop plant process in Python: the plumbing, so that a plant is `start` + `step`.

    from deltaloop import Plant

    plant = Plant()                         # parses --run-id/--config/--mode, reads the config

    def start(q0):                          # START: put the model at rest at q0 (rad)
        ...
        return q, qd, tau_hold              # rad, rad/s, and the holding torque τᵃ_0 (N m)

    def step(tau, dt):                      # apply joint torque tau (N m) for dt seconds
        ...
        return q, qd, tau_applied           # the state at the end, and the torque the model
                                            # really applied over dt (time-averaged, N m)

    sys.exit(plant.run(start, step))

`run` opens the plant's iceoryx2 ports (the QoS of protocol/transport/src/ipc.rs), says READY,
waits for START, then for each tick k = 0..=N publishes state k (with τᵃ_k), waits for the
controller's reply, lets the drives apply it and calls `step` over [t_k, t_{k+1}), publishes
telemetry k, and ends with state N + 1 flagged `STATE_FINAL` (docs/protocol.md §6, §10).

The drives are the helper's, as in the built-in plant (docs/delta-robot.md §5.2): commands are
clamped to ±`plant.tau_max_nm` (or rejected with `faults.torque_limit = "reject"`; non-finite
ones always), take effect `plant.transport_delay_samples`·Ts + `plant.transport_delay_us` after
their tick (realtime with `plant.apply_torque = "arrival"`: plus the reply's measured latency),
in tick order; an interval cut by a command taking effect inside it is passed to `step` piece by
piece, and τᵃ is the time-average of what `step` reported. `step` therefore sees any dt in
(0, Ts]. τᵃ is REQUIRED: the TDE laws estimate the robot from it (docs/protocol.md §4.1), so
`step` must return what the model really applied, never 0 for "unknown".

Ending early: a controller silent for `loop.silence_timeout_ms` (lockstep) or for
`faults.controller_silence_ticks` ticks in a row (realtime), a STOP or SIGTERM: FAULT, the final
state, then the safe stop, `faults.safe_stop_ms` of τ = hold(q) − D q̇ with D =
`faults.brake_damping_nm_s` (hold: `run`'s `hold` argument, the model's gravity torque; without
it the last applied torque). `step` raising or returning non-finite numbers: DIVERGED, the final
state, no brake. Exit codes as docs/protocol.md §10: 0 done, 2 arguments, 3 set-up, 4 fault,
5 stopped; one line on stderr for every end but 0.

Realtime: the helper sleeps to `wake_early_us` before each deadline and spins the rest; it polls
for the reply spinning when the controller has its own CPU, else in 10 µs sleeps (a Python
`timed_wait` oversleeps by milliseconds). Python leaves little margin at Ts = 0.3 ms
(python/README.md).

Not modelled by the helper: the `[sensor]` noise model (states carry the true q, q̇; `q_true`
copies them) and the payload step (a model may do it itself from `Plant.tick`).
"""

import ctypes
import gc
import math
import time
import traceback

from . import wire
from .peer import (
    EXIT_FAULT,
    EXIT_SETUP,
    EXIT_STOPPED,
    HANDSHAKE_TIMEOUT_NS,
    LOOP_BUFFER,
    OBSERVER_BUFFER,
    End,
    Peer,
    now_ns,
)
from .wire import ControlMsg, StateMsg, TelemetryMsg, TorqueMsg

__all__ = ["Plant", "Drives", "Diverged"]

_POLL_NS = 10_000  # realtime: how long the plant sleeps between looks for the reply


class Diverged(Exception):
    """Raise from `step` when the model failed (left its workspace, lost a constraint): the run
    ends as diverged at the next tick, with the message as its cause."""


class Drives:
    """The drives of docs/delta-robot.md §5.2, the twin of `Actuator` in plant/model/src/sim.rs.

    Times are integer ns from t_0. Command τ_j arrives at A_j = t_j + D + a_j and takes effect at
    E_j = max(A_j, E_{j−1}); before the first one the holding torque acts, unclamped. A rejected
    (non-finite, or beyond ±τ_max under `reject`) command leaves the torque in effect."""

    def __init__(self, tau_max, reject, delay_ns, ts_ns, tau_hold):
        self.tau_max, self.reject = float(tau_max), bool(reject)
        self.delay_ns, self.ts_ns = int(delay_ns), int(ts_ns)
        self.pending = []  # [(E_j ns, τ_j as commanded)], in order
        self.last_due = 0
        self.current = tuple(tau_hold)
        self.current_clamped = False
        self.last = tuple(tau_hold)  # τᵃ of the last interval

    def submit(self, tick, tau, latency_ns=0):
        due = max(tick * self.ts_ns + self.delay_ns + latency_ns, self.last_due)
        self.last_due = due
        self.pending.append((due, tuple(tau)))

    def _take_due(self, at_ns, flags):
        while self.pending and self.pending[0][0] <= at_ns:
            _, t = self.pending.pop(0)
            if not all(math.isfinite(x) for x in t) or (self.reject and max(abs(x) for x in t) > self.tau_max):
                flags["rejected"] = True
                continue
            c = tuple(min(max(x, -self.tau_max), self.tau_max) for x in t)
            self.current, self.current_clamped = c, c != t
            flags["clamped"] |= self.current_clamped
            flags["took_effect"] = True

    def interval(self, k):
        """Interval k = [t_k, t_{k+1}) as pieces [(length ns, torque N m)] (one piece unless a
        command takes effect inside it), and its flags (clamped, held, rejected)."""
        t0 = k * self.ts_ns
        t1 = t0 + self.ts_ns
        flags = {"clamped": False, "rejected": False, "took_effect": False}
        self._take_due(t0, flags)
        pieces, at = [], t0
        if self.pending and self.pending[0][0] < t1:
            flags["clamped"] |= self.current_clamped  # the torque carried into a cut interval
            while self.pending and self.pending[0][0] < t1:
                due = self.pending[0][0]
                if due > at:
                    pieces.append((due - at, self.current))
                at = due
                self._take_due(due, flags)
        pieces.append((t1 - at, self.current))
        held = not flags["took_effect"] and t1 > self.delay_ns  # before the first arrival: the plan
        return pieces, flags["clamped"], held, flags["rejected"]

    def apply_local(self, tau):
        """A drive-local torque (the brake), clamped, non-finite entries 0, bypassing the delay."""
        c = tuple(min(max(x, -self.tau_max), self.tau_max) if math.isfinite(x) else 0.0 for x in tau)
        self.current = self.last = c
        return c


def _vec3(v, what):
    """Three finite floats, or Diverged naming what is wrong."""
    try:
        t = tuple(float(x) for x in v)
    except (TypeError, ValueError) as e:
        raise Diverged(f"{what} is not three numbers: {e}")
    if len(t) != 3:
        raise Diverged(f"{what} has {len(t)} entries, not 3")
    if not all(math.isfinite(x) for x in t):
        raise Diverged(f"{what} is not finite: {t}")
    return t


class Plant(Peer):
    """One plant process of one run. Attributes: `run_id`, `mode`, `config` (dict), `ts` (s),
    `ticks` (N, after START), `tick` (the current k), `name` (the prefix of its stderr lines)."""

    role = "plant"

    def __init__(self, argv=None, name: str = "python-plant"):
        super().__init__(argv, name)
        lp, pl, fa = (self.config.get(s, {}) for s in ("loop", "plant", "faults"))
        self.ts_ns = round(self.ts * 1e9)
        self.budget_ns = int(lp.get("torque_budget_us", 150)) * 1000
        self.early_ns = int(self.layout.get("wake_early_us", 0) or 0) * 1000
        cpus = (self.layout.get("plant_cpu", -1), self.layout.get("controller_cpu", -1))
        self._share_cpu = cpus[0] is None or cpus[0] < 0 or cpus[0] == cpus[1]
        self.tau_max = float(pl.get("tau_max_nm", 100.0))
        self.delay_ns = int(pl.get("transport_delay_samples", 0)) * self.ts_ns + round(
            float(pl.get("transport_delay_us", 0)) * 1000
        )
        self.at_arrival = self.mode == "realtime" and pl.get("apply_torque", "arrival") == "arrival"
        self.reject = fa.get("torque_limit", "clamp") == "reject"
        self.silence_ticks = int(fa.get("controller_silence_ticks", 100))
        self.safe_stop_ms = float(fa.get("safe_stop_ms", 100))
        self.brake_damping = float(fa.get("brake_damping_nm_s", 2.0))
        self.tick = 0
        self.misses = self.late = 0

    # ---- the process -------------------------------------------------------------------------

    def run(self, start, step, hold=None) -> int:
        """Joins the run as its plant: `start(q0) -> (q, qd, tau_hold)` at START,
        `step(tau, dt) -> (q, qd, tau_applied)` for each piece of each interval, and optionally
        `hold(q) -> tau` (the gravity torque, N m) for the safe-stop brake. Returns the exit code
        (print nothing more, just `sys.exit` it)."""
        def prepare():
            self._state, self._reply = StateMsg(), TorqueMsg()
            gc.collect()  # before READY: a collection after START would eat into tick 0's deadline

        return self._join(prepare, lambda: self._loop(self._wait_start(), start, step, hold))

    def _open_ports_with(self, ports):
        state = ports.pubsub("state", StateMsg, 1, 3, OBSERVER_BUFFER)
        torque = ports.pubsub("torque", TorqueMsg, 1, 3, OBSERVER_BUFFER)
        telemetry = ports.pubsub("telemetry", TelemetryMsg, 1, 2, OBSERVER_BUFFER)
        self.state = state.publisher_builder().create()
        self.telemetry = telemetry.publisher_builder().create()
        self.torque = torque.subscriber_builder().buffer_size(LOOP_BUFFER).create()
        self.control_pub, self.control_sub = ports.control(wire.FROM_PLANT)
        self.state_ready = ports.event("state-ready").notifier_builder().create()
        self.torque_ready = ports.event("torque-ready").listener_builder().create()

    def _send(self, kind, tick=0, text=""):
        m = ControlMsg()
        m.kind, m.from_, m.tick = kind, wire.FROM_PLANT, tick
        b = text.encode("utf-8")[:160]
        while b:  # truncate at a character boundary
            try:
                b.decode("utf-8")
                break
            except UnicodeDecodeError:
                b = b[:-1]
        ctypes.memmove(m.text, b, len(b))
        self.control_pub.send_copy(m)

    def _stop_requested(self):
        while (smp := self.control_sub.receive()) is not None:
            if smp.payload().contents.kind == wire.STOP:
                self._stop = self._stop or "STOP"
            smp.delete()
        return self._stop

    def _wait_start(self):
        """START's message; End(5) on STOP or SIGTERM, End(3) after the handshake timeout."""
        timeout_ns = max(self.silence_ms * 1_000_000, HANDSHAKE_TIMEOUT_NS)
        end = now_ns() + timeout_ns
        while now_ns() < end:
            while (smp := self.control_sub.receive()) is not None:
                m = smp.payload().contents
                kind = m.kind
                if kind == wire.START:
                    start = ControlMsg()
                    ctypes.memmove(ctypes.addressof(start), ctypes.addressof(m), ctypes.sizeof(ControlMsg))
                    smp.delete()
                    self._connect_now([self.state, self.telemetry], [self.torque])
                    return start
                smp.delete()
                if kind == wire.STOP:
                    raise End(EXIT_STOPPED, "stopped before start")
            if self._stop:
                raise End(EXIT_STOPPED, "stopped before start")
            time.sleep(200e-6)  # tick 0's deadline is START + 10 ms
        raise End(EXIT_SETUP, f"no START from the supervisor within {timeout_ns // 1_000_000} ms")

    # ---- the loop ----------------------------------------------------------------------------

    def _wake(self, k):
        """(deadline, wake time) of tick k. Realtime: sleep to `wake_early_us` before t0 + k·Ts,
        then spin (a sleep's wake-up is late by tens of µs). Lockstep: both now."""
        if self.mode != "realtime":
            t = now_ns()
            return t, t
        d = self.t0_ns + k * self.ts_ns
        return d, self._wake_abs(d)

    @staticmethod
    def _trusted_stamp(claimed, pub_ns, rx_ns):
        """The reply's publish stamp if it can be true (inside [state published, reply received]),
        else our own receive time; and whether it was replaced (docs/protocol.md §8)."""
        return (claimed, False) if pub_ns <= claimed <= rx_ns else (rx_ns, True)

    def _wait_torque(self, k, until_ns, pub_ns):
        """The reply to tick k published by `until_ns` (realtime) / arriving by it (lockstep), its
        receive time, its trusted publish time and whether its stamp was replaced; or None. Late
        replies are dropped and counted, later ticks ignored."""
        spin_end = now_ns() + int(self.layout.get("spin_us", 0) or 0) * 1000
        realtime = self.mode == "realtime"
        reply = self._reply
        size = ctypes.sizeof(TorqueMsg)
        while True:
            while (smp := self.torque.receive()) is not None:
                ctypes.memmove(ctypes.addressof(reply), smp.payload_ptr, size)
                smp.delete()
                rx = now_ns()
                stamp, replaced = self._trusted_stamp(reply.t_publish_ns, pub_ns, rx)
                if reply.tick == k and (not realtime or stamp <= until_ns):
                    return reply, rx, stamp, replaced
                if reply.tick <= k:
                    self.late += 1
            t = now_ns()
            if t >= until_ns:
                return None
            if t < spin_end:
                continue
            if realtime:
                # Not the event: a Python timed_wait oversleeps by milliseconds. Spin if the
                # controller has a CPU of its own; else sleep in short slices, which let a
                # controller on our CPU, below our priority, run.
                if self._share_cpu:
                    time.sleep(min(until_ns - t, _POLL_NS) * 1e-9)
                continue
            self._wait_event(self.torque_ready, until_ns - t)
            if self._stop:
                return None

    def _publish_state(self, k, flags, q, qd, tau_a, deadline=0, wake=0):
        s = self._state
        s.tick, s.flags = k, flags
        s.q = s.q_true = q
        s.qd = s.qd_true = qd
        s.tau_applied = tau_a
        s.t_deadline_ns, s.t_wake_ns = deadline, wake
        s.t_publish_ns = now_ns()
        self.state.send_copy(s)
        self.state_ready.notify()
        return s.t_publish_ns

    def _loop(self, start_msg, start, step, hold):
        self.ticks = n = start_msg.ticks
        self.t0_ns = start_msg.t0_ns
        tel = TelemetryMsg()
        try:
            q, qd, tau_hold = start(tuple(start_msg.q0))
            q, qd = _vec3(q, "start's q"), _vec3(qd, "start's qd")
            tau_hold = _vec3(tau_hold, "start's holding torque")
        except Exception as e:
            traceback.print_exc()
            raise End(EXIT_SETUP, f"start failed at q0 = {tuple(start_msg.q0)}: {type(e).__name__}: {e}")
        drives = Drives(self.tau_max, self.reject, self.delay_ns, self.ts_ns, tau_hold)
        consecutive = 0
        gc.disable()  # no collector pauses inside the loop
        k = 0
        while True:
            self.tick = k
            deadline, wake = self._wake(k)
            if self._stop_requested():
                self._end(k, q, qd, drives, step, hold, self._stop_why(), requested=True, deadline=deadline)
            pub = self._publish_state(k, wire.STATE_FINAL if k > n else 0, q, qd, drives.last, deadline, wake)
            if k > n:
                return
            until = pub + self.budget_ns if self.mode == "realtime" else now_ns() + self.silence_ms * 1_000_000
            got = self._wait_torque(k, until, pub)
            if self._stop:
                self._end(k, q, qd, drives, step, hold, self._stop_why(), requested=True, deadline=deadline)
            tel.tick, tel.flags, tel.arrival_ns, tel.t_torque_rx_ns = k, 0, 0, 0
            if got is not None:
                reply, rx, stamp, replaced = got
                consecutive = 0
                if replaced:
                    tel.flags |= wire.TEL_STAMP_REPLACED
                latency = max(0, stamp - deadline) if self.at_arrival else 0
                drives.submit(k, tuple(reply.tau), latency)
                tel.arrival_ns, tel.t_torque_rx_ns = self.delay_ns + latency, rx
            elif self.mode != "realtime":
                self._end(
                    k, q, qd, drives, step, hold,
                    f"controller silent: no torque for tick {k} within {self.silence_ms} ms", deadline=deadline,
                )
            else:
                self.misses += 1
                consecutive += 1
                tel.flags |= wire.TEL_MISSED
                if consecutive >= self.silence_ticks:
                    self._end(
                        k, q, qd, drives, step, hold,
                        f"no torque within the budget for {consecutive} consecutive ticks "
                        f"({consecutive * self.ts * 1e3:.1f} ms; {self.late} late replies dropped)",
                        deadline=deadline,
                    )
            pieces, clamped, held, rejected = drives.interval(k)
            try:
                acc = [0.0, 0.0, 0.0]
                for length, tau in pieces:
                    q1, qd1, ta = step(tau, length * 1e-9)
                    # Validated before they replace the last good state (the final state's).
                    q, qd = _vec3(q1, "step's q"), _vec3(qd1, "step's qd")
                    ta = _vec3(ta, "step's tau_applied")
                    for i in range(3):
                        acc[i] += ta[i] * length
                drives.last = tuple(a / self.ts_ns for a in acc)
            except Exception as e:
                if not isinstance(e, Diverged):
                    traceback.print_exc()
                self._diverged(k + 1, q, qd, drives, f"{type(e).__name__}: {e}")
            tel.flags |= (
                (wire.TEL_CLAMPED if clamped else 0) | (wire.TEL_HELD if held else 0) | (wire.TEL_REJECTED if rejected else 0)
            )
            tel.misses, tel.late_dropped = self.misses, self.late
            tel.t_deadline_ns, tel.t_wake_ns, tel.t_state_pub_ns = deadline, wake, pub
            self.telemetry.send_copy(tel)
            k += 1

    def _diverged(self, k, q, qd, drives, why):
        """The model failed integrating the interval before tick k: DIVERGED, final state, exit 4."""
        self._send(wire.DIVERGED, k, why)
        self._publish_state(k, wire.STATE_FINAL, q, qd, drives.last)
        raise End(EXIT_FAULT, f"model failed at tick {k} (t = {k * self.ts:.4f} s): {why}; no safe stop possible")

    def _stop_why(self):
        return "stopped by the supervisor (STOP)" if self._stop == "STOP" else f"stopped by {self._stop}"

    def _end(self, k, q, qd, drives, step, hold, why, requested=False, deadline=0):
        """FAULT (STOPPED on request), the final state (releases the controller), the safe stop;
        End(4), or End(5) on request."""
        self._send(wire.STOPPED if requested else wire.FAULT, k, why)
        self._publish_state(k, wire.STATE_FINAL, q, qd, drives.last)
        n_stop = round(self.safe_stop_ms * 1e-3 / self.ts)
        tel = TelemetryMsg()
        held = "hold(q)" if hold is not None else "the last applied torque"
        brake = f"braked for {self.safe_stop_ms:g} ms (τ = {held} − {self.brake_damping:g} q̇)"
        try:
            for i in range(1, n_stop + 1):
                if self.mode == "realtime":
                    self._wake_abs(deadline + i * self.ts_ns)
                g = _vec3(hold(q), "hold(q)") if hold is not None else drives.last
                tau = drives.apply_local(tuple(g[j] - self.brake_damping * qd[j] for j in range(3)))
                q1, qd1, _ = step(tau, self.ts)
                q, qd = _vec3(q1, "step's q"), _vec3(qd1, "step's qd")
                tel.tick, tel.flags = k + i, wire.TEL_SAFE_STOP | wire.TEL_HELD
                tel.misses, tel.late_dropped, tel.t_wake_ns = self.misses, self.late, now_ns()
                self.telemetry.send_copy(tel)
            ended = f"then {brake}: safe stop, max |q̇| = {max(abs(x) for x in qd):.3f} rad/s"
        except Exception as e:
            ended = f"the safe stop failed: {type(e).__name__}: {e}"
        t = k * self.ts
        if requested:
            raise End(EXIT_STOPPED, f"t = {t:.4f} s: {why}; {ended}")
        raise End(EXIT_FAULT, f"fault at tick {k}: t = {t:.4f} s: {why}; {ended}")

    def _wake_abs(self, d):
        rest = d - now_ns() - self.early_ns
        if rest > 0:
            time.sleep(rest * 1e-9)
        while (t := now_ns()) < d:
            pass
        return t
