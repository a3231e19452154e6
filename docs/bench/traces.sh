#!/usr/bin/env bash
# trace.csv of every shipped run config, inproc and lockstep, with the executables in BIN_DIR,
# into OUT_DIR (one run folder each); the soak configs with a 5 s hold. Two builds' outputs
# compare with `cmp`: for f in A/*/trace.csv; do cmp "$f" "B/${f#A/}"; done
# Usage: docs/bench/traces.sh BIN_DIR OUT_DIR   (e.g. target/release /tmp/traces-new)
set -u
bin=$(realpath "$1"); out=$(realpath -m "$2"); mkdir -p "$out"
cd "$(dirname "$0")/../.."
# The run configs (the sweep configs in configs/ are not runs).
for c in configs/s1-*.toml configs/s2-*.toml configs/s3-*.toml configs/soak*.toml configs/paper/*.toml; do
    n=$(echo "$c" | tr / _ | sed 's/.toml$//')
    extra=(); case $c in *soak*) extra=(--hold-s 5) ;; esac
    for m in inproc lockstep; do
        "$bin/deltaloop" run "$c" --mode $m "${extra[@]}" --out "$out/$n-$m" --force \
            >/dev/null 2>"$out/$n-$m.err"
        echo "$n $m rc=$?"
    done
done
