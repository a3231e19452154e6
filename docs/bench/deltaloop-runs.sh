# Sourced by the bench scripts that run `deltaloop` many times: goes to the repository's top,
# takes the executable from $1 (default: a release build, built if missing), makes a scratch
# folder $out removed on exit, and prints the first line of the log (commit, time, executable).
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/../.."
bin=${1:-target/release/deltaloop}
[[ -x $bin ]] || cargo build --release --locked --bin deltaloop
out=$(mktemp -d)
trap 'rm -rf "$out"' EXIT
echo "commit $(git rev-parse --short HEAD), $(date -u +%FT%TZ), $bin, $(nproc) CPUs"
