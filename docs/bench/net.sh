#!/bin/sh
# Kept for old notes: the link benchmark is `deltaloop bench net` (docs/performance.md, "Two hosts: the link").
# Usage: [ZENOH_BRIDGE=…] docs/bench/net.sh [BIN_DIR (target/release)] [HOLD_S (9)]
exec "${1:-target/release}/deltaloop" bench net --hold-s "${2:-9}" ${ZENOH_BRIDGE:+--zenoh-bridge "$ZENOH_BRIDGE"}
