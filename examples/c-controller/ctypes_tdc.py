"""The C ABI from a second language: the Python `tdc` law (examples/python-controller) served by
deltaloop's C library through `ctypes`, not by the `deltaloop` Python package's own plumbing.

    deltaloop run configs/s1-nominal.toml --mode lockstep --law tdc \\
        --controller-cmd "<venv>/bin/python examples/c-controller/ctypes_tdc.py target/release/libdeltaloop_peer.so"

The library parses the arguments after the library's path, opens the run, calls `init` once and
`step` each tick (docs/guide/own-process.md, "C and C++").
"""

import ctypes
import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "python-controller"))
from controller import Tdc  # noqa: E402 - the law of the Python example, unchanged

from deltaloop import wire  # noqa: E402 - the ctypes wire types

INIT = ctypes.CFUNCTYPE(ctypes.c_int, ctypes.c_void_p, ctypes.c_void_p)
STEP = ctypes.CFUNCTYPE(
    ctypes.c_int,
    ctypes.c_void_p,
    ctypes.POINTER(wire.StateMsg),
    ctypes.POINTER(wire.RefSample),
    ctypes.POINTER(wire.TorqueMsg),
)


def main():
    lib = ctypes.CDLL(sys.argv[1])
    lib.dl_run_f64.argtypes = [ctypes.c_void_p, ctypes.c_char_p, ctypes.POINTER(ctypes.c_double)]
    lib.dl_run_i64.argtypes = [ctypes.c_void_p, ctypes.c_char_p, ctypes.POINTER(ctypes.c_int64)]
    lib.dl_run_str.argtypes = [ctypes.c_void_p, ctypes.c_char_p, ctypes.c_char_p, ctypes.c_size_t]
    lib.dl_run_law.argtypes = [ctypes.c_void_p]
    lib.dl_run_law.restype = ctypes.c_char_p
    lib.dl_set_error.argtypes = [ctypes.c_char_p]
    lib.dl_last_error.restype = ctypes.c_char_p
    law = {}

    def init(_user, run):
        if lib.dl_run_law(run) not in (b"", b"tdc"):
            lib.dl_set_error(b"this controller implements only tdc")
            return 1
        x, i, s = ctypes.c_double(), ctypes.c_int64(1), ctypes.create_string_buffer(64)
        c = {}
        for key in ("m_bar", "kp", "kd"):
            if lib.dl_run_f64(run, f"controller.{key}".encode(), ctypes.byref(x)) != 0:
                return 1  # dl_last_error() names the key
            c[key] = x.value
        lib.dl_run_i64(run, b"controller.tde_delay_samples", ctypes.byref(i))
        c["tde_delay_samples"] = i.value
        lib.dl_run_f64(run, b"loop.ts_s", ctypes.byref(x))
        velocity = s.value.decode() if lib.dl_run_str(run, b"sensor.velocity", s, 64) >= 0 else "measured"
        law["tdc"] = Tdc({"controller": c, "loop": {"ts_s": x.value}, "sensor": {"velocity": velocity}})
        return 0

    def step(_user, state, ref, reply):
        tau, s, n_hat, u = law["tdc"].step(state.contents, ref.contents)
        r = reply.contents
        r.tau, r.s, r.n_hat, r.u = tuple(tau), tuple(s), tuple(n_hat), tuple(u)
        return 0

    argv = [sys.argv[0].encode()] + [a.encode() for a in sys.argv[2:]]
    arr = (ctypes.c_char_p * len(argv))(*argv)
    return lib.dl_controller_main(len(argv), arr, INIT(init), STEP(step), None)


if __name__ == "__main__":
    sys.exit(main())
