#!/usr/bin/env bash
# The compensated laws against the same laws uncompensated and undelayed: inproc, matched
# preset, S2 (configs/s2-fast.toml) and S1 (configs/s1-nominal.toml), at one and two ticks of
# transport delay and at 150 and 450 µs; each cell the law's max-joint RMS over its RMS with no
# delay. Usage: docs/bench/compensation.sh [path/to/deltaloop] (default: a release build).
set -euo pipefail
cd "$(dirname "$0")/../.."
bin=${1:-target/release/deltaloop}
[[ -x $bin ]] || cargo build --release --locked --bin deltaloop
out=$(mktemp -d)
trap 'rm -rf "$out"' EXIT
echo "commit $(git rev-parse --short HEAD), $(date -u +%FT%TZ), $bin"
python3 - "$bin" "$out" <<'PY'
import json, os, subprocess, sys
binary, out = sys.argv[1], sys.argv[2]
laws = ["tdc", "tde-is", "tdc-is-sta", "tdc-is-ista"]
points = [("1 tick", ["--transport-delay", "1"]), ("150 µs", ["--transport-delay-us", "150"]),
          ("450 µs", ["--transport-delay-us", "450"]), ("2 ticks", ["--transport-delay", "2"])]
def run(cfg, extra):
    d = os.path.join(out, str(len(os.listdir(out))))
    args = [binary, "run", cfg, "--mode", "inproc", "--out", d] + [a for l in laws for a in ("--law", l)]
    subprocess.run(args + extra, check=True, capture_output=True)
    s = json.load(open(os.path.join(d, "summary.json")))
    return {l: (max(s["laws"][l]["rms_rad"]), s["laws"][l]["status"]) for l in laws}
for cfg in ["configs/s2-fast.toml", "configs/s1-nominal.toml"]:
    ideal = run(cfg, [])
    print(f"\n{cfg}: RMS / RMS at no delay (uncompensated → compensated)")
    print("| delay | " + " | ".join(laws) + " |")
    print("|---|" + "---|" * len(laws))
    print("| none (rad) | " + " | ".join(f"{ideal[l][0]:.2e}" for l in laws) + " |")
    for name, flags in points:
        a, b = run(cfg, flags), run(cfg, flags + ["--compensate", "predict"])
        def cell(l):
            ra, rb = a[l][0] / ideal[l][0], b[l][0] / ideal[l][0]
            tag = lambda r: "" if r[1] == "ok" else f" ({r[1]})"
            return f"{ra:.3g}×{tag(a[l])} → {rb:.3g}×{tag(b[l])}"
        print(f"| {name} | " + " | ".join(cell(l) for l in laws) + " |")
PY
