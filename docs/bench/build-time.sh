#!/usr/bin/env bash
# Clean-clone build and test times: clones this checkout's HEAD into a fresh folder (no target/,
# no venv), then times the README's test command (`.ci/run`, no standard input) and, in a second
# fresh clone, `cargo build --release`. Prints one line per step; run it on a quiet machine (it
# takes about 20 minutes on 2 cores). Usage: docs/bench/build-time.sh [tests|release|both]
set -euo pipefail
what=${1:-both}
src=$(git -C "$(dirname "$0")/../.." rev-parse --show-toplevel)
commit=$(git -C "$src" rev-parse --short HEAD)
echo "commit $commit, $(date -u +%FT%TZ), $(nproc) CPUs, $(uname -r)"
step() { # name dir command...
    local name=$1 dir=$2; shift 2
    local t0; t0=$(date +%s)
    (cd "$dir" && "$@" </dev/null >"$dir.log" 2>&1) && rc=0 || rc=$?
    echo "$name: rc=$rc, $(( $(date +%s) - t0 )) s wall; $(grep -m1 'Finished' "$dir.log" || true)"
}
if [[ $what != release ]]; then
    d=$(mktemp -d)/tests && git clone -q "$src" "$d"
    step ".ci/run (clean clone)" "$d" bash .ci/run
    grep -E '^test result' "$d.log" | awk '{p+=$4; f+=$6; i+=$8} END {print "tests: " p " passed, " f " failed, " i " ignored"}'
fi
if [[ $what != tests ]]; then
    d=$(mktemp -d)/release && git clone -q "$src" "$d"
    step "cargo build --release --locked (clean clone)" "$d" cargo build --release --locked
fi
