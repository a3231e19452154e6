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

import argparse
import ctypes
import gc
import os
import signal
import sys
import time
import tomllib
import traceback

import iceoryx2 as iox2

from . import services, wire
from .wire import ControlMsg, RefSample, StateMsg, TorqueMsg

# protocol/transport/src/ipc.rs
LOOP_BUFFER = 4
OBSERVER_BUFFER = 8192
REF_CHUNK = 4096
REF_RING = 16
HANDSHAKE_TIMEOUT_NS = 30_000_000_000

EXIT_SETUP, EXIT_FAULT, EXIT_STOPPED = 3, 4, 5

_WAIT_SLICE_NS = 100_000_000  # longest block on an event before looking at STOP / SIGTERM


def now_ns() -> int:
    """CLOCK_MONOTONIC, ns: the clock of every `*_ns` field."""
    return time.clock_gettime_ns(time.CLOCK_MONOTONIC)


class End(Exception):
    """Ends the process with `code`, printing `why` (one line) unless the code is 0."""

    def __init__(self, code: int, why: str = ""):
        super().__init__(why)
        self.code = code


class Controller:
    """One controller process of one run. Attributes: `run_id`, `mode`, `law`, `config` (dict),
    `ts` (s), `ticks` (N, after START), `name` (the prefix of its stderr lines)."""

    def __init__(self, argv=None, name: str = "python-controller"):
        p = argparse.ArgumentParser(prog=name, description="deltaloop controller (started by `deltaloop run`)")
        p.add_argument("--run-id", required=True)
        p.add_argument("--config", required=True)
        p.add_argument("--mode", required=True, choices=["lockstep", "realtime"])
        p.add_argument("--law", default="")
        a = p.parse_args(argv)  # exits 2 on bad arguments
        self.name = name
        self.run_id, self.mode, self.law = a.run_id, a.mode, a.law
        try:
            with open(a.config, "rb") as f:
                self.config = tomllib.load(f)
        except (OSError, tomllib.TOMLDecodeError) as e:
            self._die(EXIT_SETUP, f"cannot read the config {a.config}: {e}")
        lp = self.config.get("loop", {})
        self.ts = float(lp.get("ts_s", 3e-4))
        self.silence_ms = int(lp.get("silence_timeout_ms", 2000))
        self.layout = lp.get(self.mode, {})
        self.ticks = None
        self._stop = None  # why to stop: "STOP" or "SIGTERM"

    # ---- the process -------------------------------------------------------------------------

    def run(self, step) -> int:
        """Joins the run and answers states with `step(state, ref) -> (tau, s, n_hat, u)` until the
        run ends. Returns the exit code (print nothing more, just `sys.exit` it)."""
        try:
            self._signals()
            self._open_ports()
            self._schedule()
            self._send(wire.READY)
            self._handshake()
            self._answer_states(step)
            return 0
        except End as e:
            if e.code:
                print(f"{self.name}: {e}", file=sys.stderr, flush=True)
            return e.code

    def _die(self, code, why):
        print(f"{self.name}: {why}", file=sys.stderr, flush=True)
        sys.exit(code)

    def _signals(self):
        # As the built-in children: Ctrl-C / hang-up reach the whole group, the supervisor stops us
        # in order; SIGTERM is a clean stop; the parent's death sends us SIGTERM.
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        signal.signal(signal.SIGHUP, signal.SIG_IGN)
        signal.signal(signal.SIGTERM, lambda *_: setattr(self, "_stop", "SIGTERM"))
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(1, signal.SIGTERM, 0, 0, 0)  # PR_SET_PDEATHSIG
        libc.prctl(29, 1, 0, 0, 0)  # PR_SET_TIMERSLACK: 1 ns
        self._libc = libc

    def _schedule(self):
        """`[loop.<mode>]` controller_cpu / controller_priority / lock_memory, as the built-in
        controller applies them; what is not permitted is a one-line warning, not an error."""
        cpu, prio = self.layout.get("controller_cpu", -1), self.layout.get("controller_priority", 0)
        warn = lambda w: print(f"{self.name}: warning: {w}", file=sys.stderr, flush=True)  # noqa: E731
        if cpu is not None and cpu >= 0:
            try:
                os.sched_setaffinity(0, {cpu})
            except OSError as e:
                warn(f"cannot pin to CPU {cpu} ({e}): running unpinned")
        if prio and prio > 0:
            try:
                os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(prio))
            except OSError as e:
                warn(f"SCHED_FIFO priority {prio} not permitted ({e}): running SCHED_OTHER")
        if self.layout.get("lock_memory") and self._libc.mlockall(3) != 0:  # MCL_CURRENT | MCL_FUTURE
            warn(f"mlockall not permitted ({os.strerror(ctypes.get_errno())})")

    # ---- iceoryx2 ----------------------------------------------------------------------------

    def _open_ports(self):
        iox2.set_log_level_from_env_or(iox2.LogLevel.Error)
        cfg = iox2.config.default()
        # As deltaloop's own processes: no silent clean-up of dead nodes (the supervisor does it).
        cfg.global_cfg.node.cleanup_dead_nodes_on_creation = False
        cfg.global_cfg.node.cleanup_dead_nodes_on_destruction = False
        cfg.global_cfg.service.cleanup_dead_nodes_on_open = False
        node_name = f"deltaloop-controller-{self.run_id}"
        try:
            self.node = (
                iox2.NodeBuilder.new()
                .name(iox2.NodeName.new(node_name))
                .config(cfg)
                .signal_handling_mode(iox2.SignalHandlingMode.Disabled)
                .create(iox2.ServiceType.Ipc)
            )
        except Exception as e:
            raise End(EXIT_SETUP, f"cannot create the iceoryx2 node {node_name}: {e!r}")
        state = self._pubsub("state", StateMsg, 1, 2, OBSERVER_BUFFER)
        torque = self._pubsub("torque", TorqueMsg, 1, 2, OBSERVER_BUFFER)
        control = self._pubsub("control", ControlMsg, 3, 3, 64)
        reference = self._pubsub("reference", iox2.Slice[RefSample], 1, 1, REF_RING, borrowed=1)
        self.state = state.subscriber_builder().buffer_size(LOOP_BUFFER).create()
        self.torque = torque.publisher_builder().create()
        self.control_pub = control.publisher_builder().create()
        self.control_sub = control.subscriber_builder().create()
        self.reference = reference.subscriber_builder().buffer_size(REF_RING).create()
        self.state_ready = self._event("state-ready").listener_builder().create()
        self.torque_ready = self._event("torque-ready").notifier_builder().create()
        # The reference ring: row of tick k in slot k mod len, valid iff its tick is k. Every byte
        # 0xFF: every slot empty (tick 2^64 - 1), and every page touched now, not in the loop.
        self.ring = (RefSample * (REF_RING * REF_CHUNK))()
        ctypes.memset(self.ring, 0xFF, ctypes.sizeof(self.ring))
        self._reply = TorqueMsg()

    def _service_name(self, what):
        return f"deltaloop/{self.run_id}/{what}"

    def _pubsub(self, what, t, publishers, subscribers, buffer, borrowed=None):
        """Opens a publish-subscribe service the supervisor created, with ipc.rs's settings."""
        name = self._service_name(what)
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
            return b.open()
        except Exception as e:
            raise End(EXIT_SETUP, services.open_error(name, t, e, "controller"))

    def _event(self, what):
        """Opens (or creates: whichever of plant and controller comes first) a wake-up event."""
        name = self._service_name(what)
        try:
            return (
                self.node.service_builder(iox2.ServiceName.new(name))
                .event()
                .max_notifiers(2)
                .max_listeners(2)
                .max_nodes(4)
                .open_or_create()
            )
        except Exception as e:
            raise End(EXIT_SETUP, f"cannot open event {name} ({e!r}) on iceoryx2 0.10.0")

    def _send(self, kind):
        m = ControlMsg()
        m.kind, m.from_ = kind, wire.FROM_CONTROLLER
        self.control_pub.send_copy(m)

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
                raise End(EXIT_FAULT, f"plant silent for {self.silence_ms} ms")
            if t < spin_end:
                continue
            # Blocks until the plant notifies (it wakes at once), in slices so that STOP and
            # SIGTERM are seen. (A short timed_wait oversleeps by milliseconds: never rely on it.)
            try:
                self.state_ready.timed_wait(iox2.Duration.from_nanos(min(until - t, _WAIT_SLICE_NS)))
            except Exception:
                pass  # interrupted by a signal: look again
            if self._stop:
                raise End(EXIT_STOPPED, f"stopped by {self._stop}")
            if not self.state.has_samples():
                self._drain_control()

    def _answer_states(self, step):
        state, msg = StateMsg(), self._reply
        rows = self.ticks + 2  # ticks 0..=N + 1
        gc.collect()
        gc.disable()  # no collector pauses inside the loop (the loop allocates no cycles)
        while True:
            skipped, rx = self._wait_state(state)
            if state.flags & wire.STATE_FINAL:
                return
            if self._stop:
                raise End(EXIT_STOPPED, f"stopped by {self._stop}")
            k = state.tick
            if k >= rows:
                raise End(EXIT_FAULT, f"state tick {k} is beyond the reference ({rows} ticks)")
            ref = self._await_row(k)
            try:
                tau, s, n_hat, u = step(state, ref)
            except Exception as e:
                traceback.print_exc()
                raise End(EXIT_FAULT, f"step failed at tick {k}: {type(e).__name__}: {e}")
            msg.tick, msg.skipped = k, skipped
            msg.tau, msg.s, msg.n_hat, msg.u = tuple(tau), tuple(s), tuple(n_hat), tuple(u)
            msg.t_state_rx_ns = rx
            msg.t_publish_ns = now_ns()
            self.torque.send_copy(msg)
            self.torque_ready.notify()
            # File chunks that came meanwhile, in the slack before the next state.
            self._drain_reference()
