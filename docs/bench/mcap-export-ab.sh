#!/usr/bin/env bash
# What a tick's MCAP messages cost the supervisor, this build against a baseline binary: one
# realtime run (S1 + 5 s hold, tdc, with --mcap), then `deltaloop export --mcap` of it by each
# binary, interleaved N times (default 7); the median wall time per tick of each, their ratio, and
# whether the two exports are byte-identical. Usage:
#   docs/bench/mcap-export-ab.sh BASELINE_BINARY [N]     (release builds; this one is
#   target/release/deltaloop, or the binary in $THIS)
set -euo pipefail
cd "$(dirname "$0")/../.."
base=${1:?usage: mcap-export-ab.sh BASELINE_BINARY [N]}
n=${2:-7}
bin=${THIS:-./target/release/deltaloop}
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
echo "commit $(git rev-parse --short HEAD), $(date -u +%FT%TZ), $(nproc) CPUs, baseline $base"
$bin run configs/s1-nominal.toml --mode realtime --law tdc --hold-s 5 --out "$tmp/run" --mcap \
    >/dev/null 2>&1 || true
ticks=$(($(wc -l < "$tmp/run/trace.csv") - 1))
for i in $(seq "$n"); do
    for who in base this; do
        b=$bin; [[ $who == base ]] && b=$base
        rm -f "$tmp/$who.mcap"  # an export never replaces a file unasked
        t0=$(date +%s%N)
        $b export "$tmp/run" --mcap --out "$tmp/$who.mcap" >/dev/null
        echo "$who $(( ($(date +%s%N) - t0) / 1000 ))" >> "$tmp/times"
    done
done
python3 - "$tmp/times" "$ticks" <<'PY'
import statistics, sys
t = {"base": [], "this": []}
for line in open(sys.argv[1]):
    who, us = line.split()
    t[who].append(int(us))
ticks = int(sys.argv[2])
m = {w: statistics.median(v) for w, v in t.items()}
for w in ("base", "this"):
    print(f"{w}: export of {ticks} ticks, median {m[w]/1e3:.0f} ms ({m[w]/ticks:.1f} us/tick), "
          f"min {min(t[w])/1e3:.0f} ms, max {max(t[w])/1e3:.0f} ms")
print(f"this/base: {m['this']/m['base']:.2f}")
PY
cmp -s "$tmp/base.mcap" "$tmp/this.mcap" && echo "exports byte-identical" || echo "exports DIFFER"
