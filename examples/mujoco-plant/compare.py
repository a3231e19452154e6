"""Runs S1, S2, S3 in lockstep with the built-in plant and with the MuJoCo plant (every law of
each config) and prints the tracking side by side as a Markdown table.

    target/python-venv/bin/python examples/mujoco-plant/compare.py [--deltaloop PATH] [--out DIR]
        [--plant-args "--solref 0.02 1 --solimp 0.9"]

Per law and scenario: max-joint tracking RMS and max |e| (summary.json `rms_rad`,
`max_abs_err_rad`), max |q_MuJoCo − q_Rust| between the two runs' trajectories (trace.csv), and
the MuJoCo plant's largest forearm length error |L − Lb| (its log). Lockstep is deterministic,
so the numbers do not depend on the machine's load.
"""

import argparse
import csv
import json
import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
SCENARIOS = [("S1", "configs/s1-nominal.toml"), ("S2", "configs/s2-fast.toml"), ("S3", "configs/s3-composite.toml")]


def run(exe, cfg, out, plant_cmd=None):
    args = [str(exe), "run", cfg, "--mode", "lockstep", "--out", str(out), "--force"]
    if plant_cmd:
        args += ["--plant-cmd", plant_cmd]
    r = subprocess.run(args, cwd=ROOT, capture_output=True, text=True)
    if r.returncode != 0:
        sys.exit(f"`{' '.join(args)}` failed ({r.returncode}):\n{r.stdout}{r.stderr}")
    return json.loads((out / "summary.json").read_text())


def trajectories(out):
    """{law: [(q1, q2, q3) per tick]} from trace.csv."""
    q = {}
    with open(out / "trace.csv", newline="") as f:
        for row in csv.DictReader(f):
            q.setdefault(row["law"], []).append(tuple(float(row[f"q_{i}"]) for i in (1, 2, 3)))
    return q


def tendon_errors(out):
    """{law: max |L − Lb| in m} from the MuJoCo plant's logs."""
    err = {}
    for log in out.glob("*.plant.log"):
        m = re.search(r"\|L − Lb\| = ([0-9.e+-]+) m", log.read_text())
        if m:
            err[log.name.removesuffix(".plant.log")] = float(m.group(1))
    return err


def main():
    a = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    a.add_argument("--deltaloop", default=None, help="the deltaloop executable (default: target/release, else target/debug)")
    a.add_argument("--out", default="target/mujoco-compare", help="where the run folders go")
    a.add_argument("--plant-args", default="", help="options for examples/mujoco-plant/plant.py (--solref, --solimp)")
    o = a.parse_args()
    exe = Path(o.deltaloop) if o.deltaloop else next(
        (p for p in (ROOT / "target/release/deltaloop", ROOT / "target/debug/deltaloop") if p.is_file()), None
    )
    if exe is None:
        sys.exit("no deltaloop executable: run `cargo build --release` first, or pass --deltaloop")
    script = f"{sys.executable} {ROOT / 'examples/mujoco-plant/plant.py'}"
    if any(c.isspace() for c in script.replace(" ", "", 1)):
        sys.exit(f"--plant-cmd is split at whitespace: move the checkout or the venv ({script})")
    plant_cmd = f"{script} {o.plant_args}".strip()
    base = ROOT / o.out
    print("| scenario | law | RMS max joint (rad) built-in / MuJoCo | max \\|e\\| (rad) built-in / MuJoCo | max \\|q_MuJoCo − q_built-in\\| (rad) | max \\|L − Lb\\| (m) |")
    print("|---|---|---|---|---|---|")
    for name, cfg in SCENARIOS:
        rs_out, mj_out = base / f"{name.lower()}-builtin", base / f"{name.lower()}-mujoco"
        rs, mj = run(exe, cfg, rs_out), run(exe, cfg, mj_out, plant_cmd)
        q_rs, q_mj, tendon = trajectories(rs_out), trajectories(mj_out), tendon_errors(mj_out)
        for law, r in rs["laws"].items():
            m = mj["laws"][law]
            for s in (r, m):
                if not s["completed"] or s["lost_ticks"]:
                    sys.exit(f"{name} {law}: not completed or ticks lost: {s}")
            dq = max(abs(x - y) for a_, b_ in zip(q_rs[law], q_mj[law], strict=True) for x, y in zip(a_, b_))
            print(
                f"| {name} | {law} | {max(r['rms_rad']):.3e} / {max(m['rms_rad']):.3e} "
                f"| {max(r['max_abs_err_rad']):.3e} / {max(m['max_abs_err_rad']):.3e} "
                f"| {dq:.2e} | {tendon.get(law, float('nan')):.1e} |",
                flush=True,
            )


if __name__ == "__main__":
    main()
