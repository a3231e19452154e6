#!/usr/bin/env bash
# How a compensated law fares when the delay it assumes is wrong, and when it measures the delay
# itself: inproc, matched preset, S2 and S1, at a true transport delay of 150 µs, one tick
# (300 µs) and 450 µs, the predictor told D₀ = 0.5, 0.8, 1.2 and 1.5 × the true delay
# (`--compensate-delay-us`), and told half of it (D₀ = 0.5 × D) but measuring D from the drives'
# reports (`--compensate-delay measured`, which searches D₀ to D₀ + Ts). Each cell: the law's
# max-joint RMS over its own with no delay.
# Usage: docs/bench/compensation-delay.sh [path/to/deltaloop] (default: a release build).
source "$(dirname "$0")/deltaloop-runs.sh"
python3 - "$bin" "$out" <<'PY'
import json, os, subprocess, sys
binary, out = sys.argv[1], sys.argv[2]
laws = ["tdc", "tde-is", "tdc-is-sta", "tdc-is-ista"]
def run(config, extra):
    d = os.path.join(out, str(len(os.listdir(out))))
    args = [binary, "run", config, "--mode", "inproc", "--out", d]
    subprocess.run(args + [a for l in laws for a in ("--law", l)] + extra, check=True, capture_output=True)
    s = json.load(open(os.path.join(d, "summary.json")))
    return {l: (max(s["laws"][l]["rms_rad"]) if s["laws"][l]["status"] == "ok" else None) for l in laws}
for config in ["configs/s2-fast.toml", "configs/s1-nominal.toml"]:
    ideal = run(config, [])
    print(f"\n{config}: RMS with no delay, rad: " + ", ".join(f"{l} {ideal[l]:.3e}" for l in laws))
    print("| true D | D₀ assumed | " + " | ".join(laws) + " |")
    print("|---|---|" + "---|" * len(laws))
    for true_us in [150, 300, 450]:
        delay = ["--transport-delay-us", str(true_us)]
        rows = [("none (uncompensated)", [])]
        rows += [(f"{f} × D", ["--compensate", "predict", "--compensate-delay-us", str(f * true_us)])
                 for f in [0.5, 0.8, 1.0, 1.2, 1.5]]
        rows += [("0.5 × D, measured", ["--compensate", "predict", "--compensate-delay", "measured",
                                        "--compensate-delay-us", str(0.5 * true_us)])]
        for name, extra in rows:
            r = run(config, delay + extra)
            cells = [f"{r[l] / ideal[l]:.3g}" if r[l] else "diverged" for l in laws]
            print(f"| {true_us} µs | {name} | " + " | ".join(cells) + " |")
PY
