#!/usr/bin/env bash
# The phases of `.ci/run` in a fresh clone of this checkout's HEAD (no target/, no venv), each
# timed by wall and CPU time (CPU time compares across a loaded machine's hours, wall time does
# not): the formatting check, clippy over the test build (as .ci/run), then the README's test
# command (only running, the build being done) with its doctests and every test binary on
# a line of its own. With `e2e`, also the end-to-end binary once more on one thread, each test's
# wall time, the slowest ten last. Usage: docs/bench/ci-phases.sh [e2e]
set -euo pipefail
src=$(git -C "$(dirname "$0")/../.." rev-parse --show-toplevel)
d=$(mktemp -d)/clone && git clone -q "$src" "$d" && cd "$d"
echo "commit $(git rev-parse --short HEAD), $(date -u +%FT%TZ), $(nproc) CPUs, load $(cut -d' ' -f1-3 /proc/loadavg)"
unset CARGO_TARGET_DIR
export CARGO_INCREMENTAL=0 # as .ci/run
phase() { # name command...
    local name=$1; shift
    /usr/bin/time -f "$name: %e s wall, %U s user, %S s sys (exit %x)" -o "$d.time" "$@" \
        </dev/null >"$d.$name.log" 2>&1 || true
    cat "$d.time"
}
phase fmt cargo fmt --all -- --check
phase clippy-and-build env CLIPPY_DRIVER="$(rustc --print sysroot)/bin/clippy-driver" \
    RUSTC_WRAPPER="$d/.ci/clippy-rustc" cargo test --workspace --all-targets --locked --no-run
phase test-run cargo test --workspace --locked
grep -E '^test result' "$d.test-run.log" \
    | awk '{p+=$4; f+=$6; i+=$8} END {print "tests: " p " passed, " f " failed, " i " ignored"}'
# Each binary's wall time, as `cargo test` printed it ("finished in"), after the binary's name.
awk '/^ *Running/ {name=$NF; gsub(/[()]/, "", name); sub(/.*\//, "", name)}
    /^ *Doc-tests/ {name="doctests " $2} /^test result/ {print "  " name ": " $NF}' \
    "$d.test-run.log"
if [[ ${1:-} == e2e ]]; then
    e2e=$(cargo test --locked --test e2e --no-run --message-format=json 2>/dev/null \
        | python3 -c 'import json,sys
for l in sys.stdin:
    m = json.loads(l)
    if m.get("target", {}).get("name") == "e2e" and m.get("executable"): print(m["executable"])')
    # One thread: a test's time is the time from the line before its result to its result.
    "$e2e" --test-threads=1 </dev/null 2>&1 | python3 -u -c 'import sys, time
prev = time.monotonic(); rows = []
for line in sys.stdin:
    now = time.monotonic()
    if line.startswith("test ") and " ... " in line:
        rows.append((now - prev, line.split()[1], line.split()[-1])); prev = now
for t, name, result in rows: print(f"{t:8.2f} s  {name} {result}")
print("slowest ten:")
for t, name, result in sorted(rows, reverse=True)[:10]: print(f"{t:8.2f} s  {name}")
print(f"sum {sum(r[0] for r in rows):.0f} s over {len(rows)} tests")'
fi
