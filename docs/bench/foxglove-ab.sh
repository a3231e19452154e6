#!/usr/bin/env bash
# What `deltaloop top --foxglove` with a viewer connected costs the realtime loop it watches:
# S1 + 5 s hold, tdc, realtime, alone and watched (top --foxglove plus
# examples/foxglove/watch_live.py subscribed to every channel), interleaved (N pairs, default 5):
# the round trip's p50 and p99.9 and the misses of each run, the joint states the viewer got,
# and top's CPU time. Usage: docs/bench/foxglove-ab.sh [N] [BIN] (a release build with
# --features foxglove; BIN default ./target/release/deltaloop).
set -euo pipefail
cd "$(dirname "$0")/../.."
n=${1:-5}
bin=${2:-./target/release/deltaloop}
py=target/python-venv/bin/python
tmp=$(mktemp -d)
echo "commit $(git rev-parse --short HEAD), $(date -u +%FT%TZ), $(nproc) CPUs"
summary() { # dir label extra
    python3 - "$1" "$2" "$3" <<'PY'
import json, sys
s = json.load(open(sys.argv[1] + "/summary.json"))
t = s["timing"]["tdc"]
print(f'{sys.argv[2]:7} rtt p50 {t["round_trip"]["p50_us"]:6.1f} us  p99.9 {t["round_trip"]["p999_us"]:7.1f} us  misses {t["deadline_misses"]:4}  {sys.argv[3]}')
PY
}
for i in $(seq "$n"); do
    $bin run configs/s1-nominal.toml --mode realtime --law tdc --hold-s 5 --out "$tmp/alone-$i" \
        >/dev/null 2>&1 || true
    summary "$tmp/alone-$i" alone ""
    $bin run configs/s1-nominal.toml --mode realtime --law tdc --hold-s 5 --out "$tmp/watched-$i" \
        >/dev/null 2>&1 &
    run=$!
    url=""
    for _ in $(seq 100); do
        /usr/bin/time -f "%U %S" -o "$tmp/top-cpu" $bin top --plain --interval 5s \
            --foxglove 127.0.0.1:0 >/dev/null 2>"$tmp/top-err" &
        top=$!
        for _ in $(seq 50); do
            url=$(grep -o 'ws://[^ ]*' "$tmp/top-err" || true)
            [[ -n $url ]] && break
            kill -0 "$top" 2>/dev/null || break
            sleep 0.1
        done
        [[ -n $url ]] && break
        wait "$top" || true
        sleep 0.1
    done
    got=$($py examples/foxglove/watch_live.py "$url" 5 | awk '/joint_states/ {print $2}')
    wait "$run" || true
    wait "$top" || true
    cpu=$(awk '{print $1 + $2}' "$tmp/top-cpu")
    summary "$tmp/watched-$i" watched "viewer got ${got:-0} joint states in 5 s; top CPU ${cpu} s"
done
rm -rf "$tmp"
