"""What the Python plant and controller processes share: the command line the supervisor gives
them, the config, signals, scheduling and the iceoryx2 ports (docs/protocol.md §1.2, §6)."""

import argparse
import ctypes
import os
import signal
import sys
import time
import tomllib

import iceoryx2 as iox2

from . import services, wire

# protocol/transport/src/ipc.rs
LOOP_BUFFER = 4
OBSERVER_BUFFER = 8192
REF_CHUNK = 4096
REF_RING = 16
HANDSHAKE_TIMEOUT_NS = 30_000_000_000

EXIT_SETUP, EXIT_FAULT, EXIT_STOPPED, EXIT_PEER_SILENT = 3, 4, 5, 6

_WAIT_SLICE_NS = 50_000_000  # longest block on an event before looking at STOP / SIGTERM (protocol §13: 50 ms)
_LINGER_S = 0.02  # ports kept this long after the last message (ipc::LINGER)


def now_ns() -> int:
    """CLOCK_MONOTONIC, ns: the clock of every `*_ns` field."""
    return time.clock_gettime_ns(time.CLOCK_MONOTONIC)


class End(Exception):
    """Ends the process with `code`, printing `why` (one line) unless the code is 0."""

    def __init__(self, code: int, why: str = ""):
        super().__init__(why)
        self.code = code


class Peer:
    """One loop process of one run, in role `role` ("plant" or "controller"). Attributes:
    `run_id`, `mode`, `config` (dict), `ts` (s), `silence_ms`, `layout` (`[loop.<mode>]`),
    `ticks` (N, after START), `name` (the prefix of its stderr lines)."""

    role = ""

    def __init__(self, argv, name: str, law: bool = False):
        p = argparse.ArgumentParser(prog=name, description=f"deltaloop {self.role} (started by `deltaloop run`)")
        p.add_argument("--run-id", required=True)
        p.add_argument("--config", required=True)
        p.add_argument("--mode", required=True, choices=["lockstep", "realtime"])
        if law:
            p.add_argument("--law", default="")
        a = p.parse_args(argv)  # exits 2 on bad arguments
        self.name = name
        self.run_id, self.mode = a.run_id, a.mode
        self.law = getattr(a, "law", "")
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

    def _join(self, prepare, loop) -> int:
        """The process from start to exit code: signals, ports, scheduling, `prepare()` (what
        must happen before READY), READY, then `loop()`. An End stops it with its code and, unless
        0, its one line on stderr."""
        try:
            self._signals()
            self._open_ports()
            self._schedule()
            prepare()
            self._send(wire.READY)
            loop()
            self._linger()
            return 0
        except End as e:
            if e.code:
                print(f"{self.name}: {e}", file=sys.stderr, flush=True)
            self._linger()
            return e.code

    def _linger(self):
        """A subscriber drops what is still queued from a publisher that is gone: once its ports
        are open, the process keeps them while the supervisor (it drains every millisecond) reads
        its last messages, as the built-in processes do (`ipc::LINGER`)."""
        if getattr(self, "node", None) is not None:
            time.sleep(_LINGER_S)

    @staticmethod
    def _wait_event(listener, timeout_ns):
        """Blocks on `listener` for at most `timeout_ns`, capped at one slice so that STOP and
        SIGTERM are seen; a signal only ends the wait early. (A short timed_wait oversleeps by
        milliseconds: use it only to block, never to time.)"""
        try:
            listener.timed_wait(iox2.Duration.from_nanos(min(timeout_ns, _WAIT_SLICE_NS)))
        except Exception:  # noqa: BLE001 - interrupted by a signal: the caller looks again
            pass

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
        """`[loop.<mode>]` <role>_cpu / <role>_priority / lock_memory, as the built-in processes
        apply them; what is not permitted is a one-line warning, not an error."""
        cpu = self.layout.get(f"{self.role}_cpu", -1)
        prio = self.layout.get(f"{self.role}_priority", 0)
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

    @staticmethod
    def _connect_now(publishers, subscribers):
        """Connects the loop ports to their peers now, after START (docs/protocol.md §6, step 7):
        iceoryx2 otherwise connects in the first send or receive that sees a peer, inside tick 0's
        budget. Python subscribers have no `update_connections`; `has_samples` connects them."""
        for p in publishers:
            p.update_connections()
        for s in subscribers:
            s.has_samples()

    def _open_ports(self):
        """Creates the node and opens every port (`_open_ports_with`); a failure ends the process
        with exit code 3 and one line."""
        try:
            ports = services.RunPorts(self.role, self.run_id)
            self.node = ports.node
            self._open_ports_with(ports)
        except services.SetupError as e:
            raise End(EXIT_SETUP, str(e)) from None

    def _open_ports_with(self, ports: services.RunPorts):
        raise NotImplementedError
