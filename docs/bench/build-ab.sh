#!/usr/bin/env bash
# Clean-clone build times of two commits side by side: ROUNDS clean `cargo build --release
# --locked`, each in a fresh clone, alternating OLD and NEW, then one `.ci/run </dev/null` (the
# README's test command) of each commit named in CI_OF (default: NEW). Keeps the first round's
# release executables in OUT/bin-<commit> for run-time A/Bs. Run it on a quiet machine (about
# 20 minutes on 2 cores). Usage: docs/bench/build-ab.sh OLD NEW [ROUNDS] [OUT] [CI_OF...]
set -u
old=$1 new=$2 rounds=${3:-3} out=${4:-/tmp/build-ab}
shift $(( $# < 4 ? $# : 4 ))
ci_of=("${@:-$new}")
src=$(git -C "$(dirname "$0")/../.." rev-parse --show-toplevel)
mkdir -p "$out"
echo "old $old, new $new, $(date -u +%FT%TZ), $(nproc) CPUs, $(uname -r)"
clone() { local d; d=$(mktemp -d)/c && git clone -q "$src" "$d" && git -C "$d" checkout -q "$1" && echo "$d"; }
for round in $(seq "$rounds"); do
    for c in $old $new; do
        d=$(clone "$c")
        t0=$(date +%s); (cd "$d" && cargo build --release --locked </dev/null >"$d.log" 2>&1); rc=$?
        echo "release $c round $round: rc=$rc, $(( $(date +%s) - t0 )) s wall"
        if [[ $round == 1 ]]; then
            mkdir -p "$out/bin-$c"
            cp "$d"/target/release/deltaloop{,-plant,-controller,-bridge} "$out/bin-$c/"
        fi
        rm -rf "$(dirname "$d")"
    done
done
for c in "${ci_of[@]}"; do
    d=$(clone "$c")
    t0=$(date +%s); (cd "$d" && bash .ci/run </dev/null >"$d.log" 2>&1); rc=$?
    echo ".ci/run $c: rc=$rc, $(( $(date +%s) - t0 )) s wall; $(grep -E '^test result' "$d.log" | awk '{p+=$4; f+=$6; i+=$8} END {print p " passed, " f " failed, " i " ignored"}')"
    rm -rf "$(dirname "$d")"
done
