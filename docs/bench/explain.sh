#!/usr/bin/env bash
# `--explain` on this host (root): (1) its overhead, five realtime S1 runs (all four laws) with and
# five without it, interleaved: each pair's misses and round-trip and wake-up p99.9 (µs), and the
# kernel events a second it read; (2) ten quiet realtime S1 runs with it: the missed and late
# ticks by cause, summed, and the top culprits: how much of this host's jitter is its own.
# Usage: docs/bench/explain.sh [path/to/deltaloop] (default: a release build).
source "$(dirname "$0")/deltaloop-runs.sh"
python3 - "$bin" "$out" <<'PY'
import collections, json, os, statistics, subprocess, sys
binary, out = sys.argv[1], sys.argv[2]
def run(extra):
    d = os.path.join(out, str(len(os.listdir(out))))
    subprocess.run([binary, "run", "configs/s1-nominal.toml", "--mode", "realtime", "--out", d] + extra,
                   capture_output=True)
    return json.load(open(os.path.join(d, "summary.json")))["timing"]
def cells(t):
    misses = sum(x["deadline_misses"] for x in t.values())
    rtt = max(x["round_trip"]["p999_us"] for x in t.values())
    wake = max(x["wake_lateness"]["p999_us"] for x in t.values())
    return misses, rtt, wake
rows = {"without": [], "with": []}
rate = []
for i in range(5):
    for name, extra in [("without", []), ("with", ["--explain"])]:
        t = run(extra)
        rows[name].append(cells(t))
        if extra:
            rate += [x["sched_events_per_s"] for x in t.values()]
        m, r, w = rows[name][-1]
        print(f"pair {i + 1} {name:7} --explain: misses {m:3}, round trip p99.9 {r:7.1f} µs (worst law), wake p99.9 {w:6.1f} µs")
for name, v in rows.items():
    print(f"median {name:7}: misses {statistics.median(x[0] for x in v)}, round trip p99.9 "
          f"{statistics.median(x[1] for x in v):.1f} µs, wake p99.9 {statistics.median(x[2] for x in v):.1f} µs")
print(f"kernel events read: median {statistics.median(rate):.0f} a second (min {min(rate):.0f}, max {max(rate):.0f})")
missed, late, culprits, runs = collections.Counter(), collections.Counter(), collections.Counter(), 0
for i in range(10):
    t = run(["--explain"])
    runs += 1
    for x in t.values():
        missed.update(x["miss_causes"])
        late.update(x["late_causes"])
        culprits.update(x["miss_culprits"])
def share(c):
    n = sum(c.values())
    return f"{n} ticks" + "".join(f", {k} {v} ({100 * v / n:.0f} %)" for k, v in c.most_common() if v) if n else "0 ticks"
print(f"ten quiet runs (4 laws each), missed: {share(missed)}")
print(f"ten quiet runs, late (plant woke ≥ Ts/4 late): {share(late)}")
print("top culprits of missed ticks: " + (", ".join(f"{k} {v}" for k, v in culprits.most_common(5)) or "none"))
PY
