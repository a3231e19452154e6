#!/usr/bin/env bash
# What writing <law>.mcap while a run records costs the realtime loop: S1 + 5 s hold, tdc,
# realtime, with and without --mcap, interleaved (N pairs, default 5), the round trip's p50 and
# p99.9 and the misses of each run; then the file's bytes per tick and the export's wall time
# per tick. Usage: docs/bench/mcap-ab.sh [N] (release build).
set -euo pipefail
cd "$(dirname "$0")/../.."
n=${1:-5}
bin=./target/release/deltaloop
tmp=$(mktemp -d)
echo "commit $(git rev-parse --short HEAD), $(date -u +%FT%TZ), $(nproc) CPUs"
for i in $(seq "$n"); do
    for m in plain mcap; do
        flag=(); [[ $m == mcap ]] && flag=(--mcap)
        $bin run configs/s1-nominal.toml --mode realtime --law tdc --hold-s 5 \
            --out "$tmp/$m-$i" "${flag[@]}" >/dev/null 2>&1 || true
        python3 - "$tmp/$m-$i" "$m" <<'PY'
import json, sys
s = json.load(open(sys.argv[1] + "/summary.json"))
t = s["timing"]["tdc"]
print(f'{sys.argv[2]:5} rtt p50 {t["round_trip"]["p50_us"]:6.1f} us  p99.9 {t["round_trip"]["p999_us"]:7.1f} us  misses {t["deadline_misses"]}')
PY
    done
done
ticks=$(($(wc -l < "$tmp/mcap-1/trace.csv") - 1))
bytes=$(stat -c %s "$tmp/mcap-1/tdc.mcap")
echo "live tdc.mcap: $bytes bytes, $ticks ticks, $((bytes / ticks)) bytes/tick"
t0=$(date +%s.%N); $bin export "$tmp/plain-1" --mcap >/dev/null; t1=$(date +%s.%N)
python3 -c "print(f'export of {${ticks}} ticks: {($t1-$t0)*1e3:.0f} ms, {($t1-$t0)*1e6/$ticks:.1f} us/tick')"
rm -rf "$tmp"
