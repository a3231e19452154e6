#!/usr/bin/env bash
# A crate whose `[lib]` says `doctest = false` holds no Rust code block in its doc comments
# (rustdoc would not run one there): prints each such block's file and line, fails if any.
set -euo pipefail
cd "$(dirname "$0")/.."
found=0
for manifest in $(git ls-files '*Cargo.toml' | grep -v '^vendor/'); do
    grep -q '^doctest = false' "$manifest" || continue
    dir=$(dirname "$manifest")
    # An opening fence with no language, or a Rust one (rust, no_run, should_panic, ...).
    hits=$(git ls-files "$dir/src" | grep '\.rs$' | xargs -r awk '
        FNR == 1 { open = 0 }
        /^[ \t]*\/\/[\/!][ \t]*```/ {
            info = $0; sub(/^[ \t]*\/\/[\/!][ \t]*```[ \t]*/, "", info)
            if (!open && (info == "" || info ~ /rust|no_run|should_panic|compile_fail|edition/))
                print FILENAME ":" FNR
            open = !open
        }')
    if [[ -n $hits ]]; then
        echo "$manifest has doctest = false, but its docs hold Rust code blocks rustdoc would run:"
        echo "$hits"
        found=1
    fi
done
exit $found
