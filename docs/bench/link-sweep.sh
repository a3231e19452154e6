#!/usr/bin/env bash
# The link-delay table of docs/guide/delay-study.md: runs `deltaloop sweep configs/link-sweep.toml`
# N times (default 10) into OUT (default docs/bench/link-sweep) and prints, per law and delay, the
# ranges over the runs and the match counts. Usage: docs/bench/link-sweep.sh [N] [OUT]
set -euo pipefail
cd "$(dirname "$0")/../.."
n="${1:-10}"
out="${2:-docs/bench/link-sweep}"
mkdir -p "$out"
for i in $(seq 1 "$n"); do
  rm -rf "$out/run$i"
  ./target/release/deltaloop sweep configs/link-sweep.toml --out "$out/run$i.tmp" >/dev/null
  # Keep the table only (the point folders hold megabytes of per-tick files).
  mkdir -p "$out/run$i" && cp "$out/run$i.tmp/sweep.csv" "$out/run$i/" && rm -rf "$out/run$i.tmp"
done
python3 - "$out" "$n" <<'PY'
import csv, sys, collections
out, n = sys.argv[1], int(sys.argv[2])
rows = collections.defaultdict(list)
for i in range(1, n + 1):
    for r in csv.DictReader(open(f"{out}/run{i}/sweep.csv")):
        if r["link_delay_us"]:
            rows[(r["law"], float(r["link_delay_us"]))].append(r)
def rng(vals, fmt):
    vals = [v for v in vals if v is not None]
    return "–" if not vals else f"{fmt(min(vals))}–{fmt(max(vals))}"
f = lambda s: float(s) if s not in ("", "NaN", "nan") else None
print("| law | D each way (µs) | link round trip p50 (µs) | median arrival (µs) | RMS injected (rad) | undisturbed runs | matched (±10 %) | difference in those runs |")
print("|---|---|---|---|---|---|---|---|")
for (law, d), rs in sorted(rows.items()):
    ok = [r for r in rs if r["status"] == "ok"]
    und = [r for r in ok if not r["link_disturbed"] and f(r["injected_rms_rad"])]
    diffs = sorted(f(r["rms_rad"]) / f(r["injected_rms_rad"]) - 1 for r in und)
    matched = sum(abs(x) <= 0.10 for x in diffs)
    faults = len(rs) - len(ok)
    print(f"| `{law}` | {d:g} | {rng([f(r['link_rtt_p50_us']) for r in ok], lambda v: f'{v:.0f}')} "
          f"| {rng([f(r['median_arrival_us']) for r in ok], lambda v: f'{v:.0f}')} "
          f"| {rng([f(r['injected_rms_rad']) for r in ok], lambda v: f'{v:.1e}')} "
          f"| {len(und)} of {len(rs)}{f' ({faults} not ok)' if faults else ''} | {matched} "
          f"| {', '.join(f'{x * 100:+.1f} %' for x in diffs) or '–'} |")
PY
