#!/usr/bin/env bash
# Realtime S1 over the process pair with 150 µs of transport delay, uncompensated, with
# `--compensate predict` over the configured 150 µs, and with the delay measured from the drives'
# reports (`--compensate-delay measured`: the configured 150 µs plus the loop's own latency),
# three interleaved triples: each law's max-joint RMS over its inproc RMS
# with no delay, the run's status, its deadline misses, and whether its record says the host
# disturbed it. Usage: docs/bench/compensation-rt.sh [path/to/deltaloop] (default: release).
source "$(dirname "$0")/deltaloop-runs.sh"
python3 - "$bin" "$out" <<'PY'
import json, os, subprocess, sys
binary, out = sys.argv[1], sys.argv[2]
laws = ["tdc", "tde-is", "tdc-is-ista"]
def run(mode, extra):
    d = os.path.join(out, str(len(os.listdir(out))))
    args = [binary, "run", "configs/s1-nominal.toml", "--mode", mode, "--out", d]
    subprocess.run(args + [a for l in laws for a in ("--law", l)] + extra, capture_output=True)
    return json.load(open(os.path.join(d, "summary.json")))
ideal = run("inproc", [])
base = {l: max(ideal["laws"][l]["rms_rad"]) for l in laws}
print("inproc, no delay, rad: " + ", ".join(f"{l} {base[l]:.3e}" for l in laws))
for i in range(3):
    for name, extra in [("none", []), ("predict", ["--compensate", "predict"]),
                        ("measured", ["--compensate", "predict", "--compensate-delay", "measured"])]:
        s = run("realtime", ["--transport-delay-us", "150"] + extra)
        def cell(l):
            m, t = s["laws"][l], s["timing"][l]
            rms = max(m["rms_rad"]) / base[l] if m.get("rms_rad") else float("nan")
            dist = ", disturbed" if t.get("disturbance") else ""
            return f"{l} {rms:.3g}× {m['status']} ({t['deadline_misses']} misses{dist})"
        print(f"triple {i + 1}, {name:8}: " + "; ".join(cell(l) for l in laws))
PY
