"""MuJoCo's wall seconds per simulated second on this robot: the MuJoCo half of `deltaloop bench plant`.

    target/python-venv/bin/python examples/mujoco-plant/bench.py --q0 Q1,Q2,Q3 --tau T1,T2,T3 \
        --steps 66670 --segment-steps 10000 --h 3e-05

The motion is the one `bench plant` gives the built-in plant (the spec's MuJoCo cross-check,
docs/delta-robot.md §7.3): from rest at q0 (rad) under the constant joint torque tau (N m), RK4 at
step h (s), restarted from rest every `--segment-steps` steps until `--steps` steps are done.
The model is plant.py's (`mjcf`, stiff forearm constraints), friction off: the Coulomb term
would be a Python callback at every stage, the interpreter's cost rather than MuJoCo's.

Only MuJoCo's stepping is timed: time.perf_counter() around each segment's single
`mj_step(m, d, nstep=n)` call. The interpreter's start, the imports, compiling the model and the
resets to rest (`mj_forward`) are not. Prints one JSON line: `mujoco` (its version), `wall_s`, `sim_s`,
`wall_per_sim_s`, and `q_segment` (q after the first segment, so that the caller can check that
MuJoCo ran the same motion).
"""

import argparse
import json
import sys
import time
from pathlib import Path

import mujoco
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from plant import DeltaMujoco  # noqa: E402


def vec3(text):
    """Three comma-separated numbers (a negative one would read as an option after a space)."""
    v = [float(x) for x in text.split(",")]
    if len(v) != 3:
        raise argparse.ArgumentTypeError(f"`{text}`: expected three comma-separated numbers")
    return v


def main():
    a = argparse.ArgumentParser(prog="mujoco-bench", description=__doc__.splitlines()[0])
    a.add_argument("--q0", type=vec3, required=True, metavar="Q1,Q2,Q3")
    a.add_argument("--tau", type=vec3, required=True, metavar="T1,T2,T3")
    a.add_argument("--steps", type=int, required=True, help="RK4 steps in all")
    a.add_argument("--segment-steps", type=int, required=True, help="RK4 steps between restarts from rest")
    a.add_argument("--h", type=float, required=True, help="RK4 step, s")
    o = a.parse_args()
    if not (o.steps > 0 and o.segment_steps > 0 and o.h > 0):
        a.error("--steps, --segment-steps and --h must be > 0")
    sim = DeltaMujoco(o.h, False, 100.0)
    m, d = sim.m, sim.d
    q0, tau = np.array(o.q0), np.array(o.tau)
    wall, done, q_segment = 0.0, 0, None
    while done < o.steps:
        n = min(o.segment_steps, o.steps - done)
        sim.set_state(q0)
        d.ctrl[:] = tau
        t0 = time.perf_counter()
        mujoco.mj_step(m, d, nstep=n)
        wall += time.perf_counter() - t0
        if q_segment is None:
            q_segment = d.qpos[:3].tolist()
        done += n
    if not np.all(np.isfinite(d.qpos)):
        sys.exit(f"mujoco-bench: state not finite: qpos = {d.qpos}")
    sim_s = o.steps * o.h
    print(json.dumps({"mujoco": mujoco.__version__, "wall_s": wall, "sim_s": sim_s, "wall_per_sim_s": wall / sim_s, "q_segment": q_segment}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
