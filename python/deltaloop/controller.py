"""A deltaloop controller process in Python: the plumbing, so that a law is one `step` function.

    from deltaloop import Controller

    ctl = Controller()                      # parses --run-id/--config/--mode/--law, reads the config
    gains = ctl.config["controller"]        # the resolved config (a dict, from TOML)

    def step(state, ref):                   # state: wire.StateMsg, ref: wire.RefSample (tick k)
        ...
        return tau, s, n_hat, u             # three floats each; s, n_hat, u only go to the trace

    sys.exit(ctl.run(step))

`run` opens the iceoryx2 ports of the run (the QoS of protocol/transport/src/ipc.rs), does the
handshake (READY, reference chunks into a ring, ARMED, START), then answers the newest state
with `step` until the final state. It returns the exit code of docs/protocol.md §10 and prints
one line on stderr for every end but 0: 3 set-up failed (config, a service that cannot be opened
with these types), 4 the loop failed (plant silent, reference missing, `step` raised), 5 stopped
(STOP from the supervisor, or SIGTERM).
"""

import ctypes
import gc
import time
import traceback

import iceoryx2 as iox2

from . import wire
from .wire import ControlMsg, RefSample, StateMsg, TorqueMsg

from .peer import (  # noqa: F401 - re-exported: the constants were first defined here
    EXIT_FAULT,
    EXIT_PEER_SILENT,
    EXIT_SETUP,
    EXIT_STOPPED,
    HANDSHAKE_TIMEOUT_NS,
    LOOP_BUFFER,
    OBSERVER_BUFFER,
    REF_CHUNK,
    REF_RING,
    End,
    Peer,
    now_ns,
)


class Controller(Peer):
    """One controller process of one run. Attributes: `run_id`, `mode`, `law`, `config` (dict),
    `ts` (s), `ticks` (N, after START), `name` (the prefix of its stderr lines)."""

    role = "controller"

    def __init__(self, argv=None, name: str = "python-controller"):
        super().__init__(argv, name, law=True)

    # ---- the process -------------------------------------------------------------------------

    def run(self, step) -> int:
        """Joins the run and answers states with `step(state, ref) -> (tau, s, n_hat, u)` until the
        run ends. Returns the exit code (print nothing more, just `sys.exit` it)."""
        return self._join(lambda: None, lambda: (self._handshake(), self._answer_states(step)))

    def _open_ports_with(self, ports):
        state = ports.pubsub("state", StateMsg, 1, 2, OBSERVER_BUFFER)
        torque = ports.pubsub("torque", TorqueMsg, 1, 2, OBSERVER_BUFFER)
        reference = ports.pubsub("reference", iox2.Slice[RefSample], 1, 1, REF_RING, borrowed=1)
        self.state = state.subscriber_builder().buffer_size(LOOP_BUFFER).create()
        self.torque = torque.publisher_builder().create()
        self.control_pub, self.control_sub = ports.control(wire.FROM_CONTROLLER)
        self.reference = reference.subscriber_builder().buffer_size(REF_RING).create()
        self.state_ready = ports.event("state-ready").listener_builder().create()
        self.torque_ready = ports.event("torque-ready").notifier_builder().create()
        # The reference ring: row of tick k in slot k mod len, valid iff its tick is k. Every byte
        # 0xFF: every slot empty (tick 2^64 - 1), and every page touched now, not in the loop.
        self.ring = (RefSample * (REF_RING * REF_CHUNK))()
        ctypes.memset(self.ring, 0xFF, ctypes.sizeof(self.ring))
        self._reply = TorqueMsg()

    def _send(self, kind):
        m = ControlMsg()
        m.kind, m.from_ = kind, wire.FROM_CONTROLLER
        self.control_pub.send_copy(m)

    def _tell_plant_the_step_failed(self, k, why):
        """CONTROLLER_ERROR at tick `k` (protocol §3), and the plant woken: it stops the loop at
        once, naming `why`, instead of holding the last torque through its silence window."""
        m = ControlMsg()
        m.kind, m.from_, m.tick = wire.CONTROLLER_ERROR, wire.FROM_CONTROLLER, k
        # Cut to the field, never in the middle of a character.
        text = why.encode()[: len(m.text)].decode("utf-8", "ignore").encode()
        ctypes.memmove(m.text, text, len(text))
        self.control_pub.send_copy(m)
        self.torque_ready.notify()

    def _drain_control(self):
        """START's N if START came (else None); raises End on STOP or SIGTERM."""
        start = None
        while (smp := self.control_sub.receive()) is not None:
            m = smp.payload().contents
            if m.kind == wire.START:
                start = m.ticks
            elif m.kind == wire.STOP:
                self._stop = self._stop or "STOP"
            smp.delete()
        if self._stop:
            raise End(EXIT_STOPPED, f"stopped by {self._stop}")
        return start

    # ---- the reference -----------------------------------------------------------------------

    def _drain_reference(self):
        """Files every queued chunk into the ring, releasing each before taking the next."""
        ring, n_ring = self.ring, len(self.ring)
        size = ctypes.sizeof(RefSample)
        while (smp := self.reference.receive()) is not None:
            # iceoryx2 #1533: `payload().len()` is in bytes on 0.10.0; the header counts elements.
            rows = smp.header.number_of_elements
            ptr = smp.payload_ptr
            chunk = (RefSample * rows).from_address(ptr)
            first = chunk[0].tick if rows else 0
            slot = first % n_ring
            if rows and slot + rows <= n_ring and chunk[rows - 1].tick == first + rows - 1:
                ctypes.memmove(ctypes.addressof(ring) + slot * size, ptr, rows * size)
            else:  # not one run of ticks: file row by row
                for r in chunk:
                    ctypes.memmove(ctypes.addressof(ring) + (r.tick % n_ring) * size, ctypes.addressof(r), size)
            del chunk
            smp.delete()

    def _row(self, k):
        r = self.ring[k % len(self.ring)]
        return r if r.tick == k else None

    def _await_row(self, k):
        """Tick k's row; if the supervisor fell behind, waits for it up to the silence timeout."""
        until = now_ns() + self.silence_ms * 1_000_000
        while (r := self._row(k)) is None:
            self._drain_reference()
            self._drain_control()
            if now_ns() >= until:
                raise End(
                    EXIT_FAULT,
                    f"no reference for tick {k} from the supervisor within {self.silence_ms} ms: it fell behind the loop",
                )
            time.sleep(50e-6)
        return r

    # ---- handshake and loop ------------------------------------------------------------------

    def _handshake(self):
        """READY is sent. File chunks until tick 0's row is there, say ARMED, wait for START
        (filing the rest meanwhile); note START's N."""
        end = now_ns() + HANDSHAKE_TIMEOUT_NS
        start = None
        armed = False
        while start is None:
            self._drain_reference()
            if not armed and self._row(0) is not None:
                self._send(wire.ARMED)
                armed = True
            start = self._drain_control()
            if now_ns() > end:
                what = "START" if armed else "reference"
                raise End(EXIT_SETUP, f"no {what} from the supervisor within 30 s")
            time.sleep(200e-6 if armed else 1e-3)
        self.ticks = start
        self._connect_now([self.torque], [self.state])

    def _wait_state(self, state):
        """Copies the newest state into `state`; returns (older states skipped, when it was taken in ns)."""
        spin_end = now_ns() + int(self.layout.get("spin_us", 0) or 0) * 1000
        until = now_ns() + self.silence_ms * 1_000_000
        size = ctypes.sizeof(StateMsg)
        while True:
            seen = 0
            while (smp := self.state.receive()) is not None:
                ctypes.memmove(ctypes.addressof(state), smp.payload_ptr, size)
                smp.delete()
                seen += 1
            if seen:
                return seen - 1, now_ns()
            t = now_ns()
            if t >= until:
                raise End(EXIT_PEER_SILENT, f"plant silent for {self.silence_ms} ms")
            if t < spin_end:
                continue
            # Blocks until the plant notifies (it wakes at once).
            self._wait_event(self.state_ready, until - t)
            if self._stop:
                raise End(EXIT_STOPPED, f"stopped by {self._stop}")
            if not self.state.has_samples():
                self._drain_control()

    def _answer_states(self, step):
        state, msg = StateMsg(), self._reply
        rows = self.ticks + 2  # ticks 0..=N + 1
        gc.collect()
        gc.disable()  # no collector pauses inside the loop (the loop allocates no cycles)
        answered = None
        while True:
            skipped, rx = self._wait_state(state)
            if state.flags & wire.STATE_FINAL:
                self._drain_control()  # the plant releases us after a STOP too: exit 5 then
                return
            if self._stop:
                raise End(EXIT_STOPPED, f"stopped by {self._stop}")
            k = state.tick
            if answered is not None and k <= answered:
                continue  # not newer than a state already answered: one reply per tick
            answered = k
            if k >= rows:
                raise End(EXIT_FAULT, f"state tick {k} is beyond the reference ({rows} ticks)")
            ref = self._await_row(k)
            try:
                tau, s, n_hat, u = step(state, ref)
            except Exception as e:
                traceback.print_exc()
                why = f"step failed at tick {k}: {type(e).__name__}: {e}"
                self._tell_plant_the_step_failed(k, why)
                raise End(EXIT_FAULT, why)
            msg.tick, msg.skipped = k, skipped
            msg.tau, msg.s, msg.n_hat, msg.u = tuple(tau), tuple(s), tuple(n_hat), tuple(u)
            msg.t_state_rx_ns = rx
            msg.t_publish_ns = now_ns()
            self.torque.send_copy(msg)
            self.torque_ready.notify()
            # File chunks that came meanwhile, in the slack before the next state.
            self._drain_reference()
