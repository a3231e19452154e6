#!/usr/bin/env bash
# The numbers of docs/performance.md "ROS 2 over DDS", on this checkout's release build (build it
# first: cargo build --release --locked) and the tests' venv (target/python-venv, with python/
# installed: `target/python-venv/bin/pip install --no-deps ./python`). Run it on a quiet machine
# (about 6 minutes). Usage: docs/bench/ros2.sh [aa|controller|build COMMIT] (default: aa, then
# controller).
#   aa          4 rounds of A, A, B: realtime S1 + 5 s hold, tdc; A without --ros2, B with --ros2
#               and a Cyclone watcher (examples/ros2/watch.py) subscribed, so the samples go out
#   controller  3 rounds of configs/s1-ros2.toml in realtime: the built-in controller, then the
#               Cyclone tdc node (examples/ros2/controller.py) with --controller ros2
#   build C     clean release builds of commit C in a fresh clone, with and without the `ros2`
#               feature, alternating, two rounds
set -u
root=$(git -C "$(dirname "$0")/../.." rev-parse --show-toplevel); cd "$root"
dl=./target/release/deltaloop py=target/python-venv/bin/python out=${OUT:-/tmp/deltaloop-ros2-bench}
line() { python3 -c "
import json; s = json.load(open('$1/summary.json')); t = s['timing']['tdc']; l = s['laws']['tdc']
print('$2', l['status'], 'rms_rad=%.3e rtt_p50_us=%.1f rtt_p99_us=%.1f rtt_p999_us=%.1f misses=%d late=%d skipped=%d ticks=%d' % (max(l['rms_rad']), t['round_trip']['p50_us'], t['round_trip']['p99_us'], t['round_trip']['p999_us'], t['deadline_misses'], t['late_replies_dropped'], t['controller_skipped_states'], t['ticks']))"; }
aa() {
    for r in 1 2 3 4; do
        for v in A1 A2 B; do
            d=$out/aa-$r-$v
            if [[ $v == B ]]; then
                $py examples/ros2/watch.py --domain 99 --law tdc --out "$d.jsonl" --idle-s 10 >/dev/null 2>&1 & w=$!
                sleep 2
                ROS_DOMAIN_ID=99 $dl run configs/s1-nominal.toml --law tdc --mode realtime --hold-s 5 --ros2 --out "$d" >/dev/null 2>&1
                wait $w
                echo "$(wc -l <"$d.jsonl") samples seen by the watcher"
            else
                $dl run configs/s1-nominal.toml --law tdc --mode realtime --hold-s 5 --out "$d" >/dev/null 2>&1
            fi
            line "$d" "$(date -u +%T) round $r $v"
        done
    done
}
controller() {
    for r in 1 2 3; do
        $dl run configs/s1-ros2.toml --mode realtime --out "$out/ctl-$r-builtin" >/dev/null 2>&1
        line "$out/ctl-$r-builtin" "$(date -u +%T) round $r builtin"
        d=$out/ctl-$r-ros2
        ROS_DOMAIN_ID=96 $dl run configs/s1-ros2.toml --mode realtime --controller ros2 --out "$d" >/dev/null 2>&1 & run=$!
        while [[ ! -f $d/config.toml ]]; do sleep 0.05; done
        $py examples/ros2/controller.py --config "$d/config.toml" --domain 96 --idle-s 2 2>/dev/null
        wait $run
        line "$d" "$(date -u +%T) round $r ros2"
    done
}
build() {
    local d; d=$(mktemp -d)/c; git clone -q "$root" "$d"; git -C "$d" checkout -q "$1"
    for r in 1 2; do
        for f in default none; do
            rm -rf "$d/target"
            args=(--release --locked); [[ $f == none ]] && args+=(--no-default-features)
            t0=$(date +%s.%N); (cd "$d" && cargo build "${args[@]}" >/dev/null 2>&1); rc=$?
            echo "$(date -u +%T) round $r features=$f rc=$rc wall_s=$(echo "$(date +%s.%N) - $t0" | bc)"
        done
    done
}
rm -rf "$out"; mkdir -p "$out"
echo "deltaloop $(git rev-parse --short HEAD), $(date -u +%FT%TZ), $(nproc) CPUs, load $(cut -d' ' -f1-3 /proc/loadavg)"
case ${1:-all} in
    aa) aa ;;
    controller) controller ;;
    build) build "$2" ;;
    *) aa; controller ;;
esac
