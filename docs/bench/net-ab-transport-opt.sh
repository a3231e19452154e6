#!/usr/bin/env bash
# A/B of the relay path: `deltaloop bench net` (S1 + 9 s hold) with two release builds,
# interleaved, RUNS runs each (default 5). For the transport's opt-level: A = a checkout as
# committed (deltaloop-transport at opt-level 0 in release), B = a second checkout without the
# [profile.release.package.deltaloop-transport] override, each built with its own target folder.
# Needs root and iproute2 (bench net). Usage: net-ab-transport-opt.sh A_DELTALOOP B_DELTALOOP [RUNS]
set -u
a=$1 b=$2 runs=${3:-5}
echo "# deltaloop bench net (S1 + 9 s hold, tdc, realtime; release builds): A = $a, B = $b; interleaved A/B, $runs runs each, $(date -u +%F' '%H:%M) UTC, $(nproc) CPUs. Each block is one run's stdout; 'rc' its exit status."
for i in $(seq "$runs"); do
    for v in A B; do
        if [ "$v" = A ]; then bin=$a; else bin=$b; fi
        echo; echo "== $v run $i $(date -u +%T) =="
        "$bin" bench net 2>&1; echo "rc=$?"
    done
done
