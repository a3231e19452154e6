#!/bin/bash
# The link benchmark of docs/performance.md ("Two hosts: the link"): two network namespaces of
# this machine joined by a veth pair, each with its own iceoryx2 root, and in the same run
#   1. a plain UDP ping-pong of state-sized datagrams, one per 300 µs (deltaloop-bridge ping/pong),
#   2. realtime S1 + hold (tdc) across deltaloop-bridge, bridges blocking / the near or the far one
#      polling for the reply,
#   3. the same run on one host (no bridge), for reference,
#   4. with ZENOH_BRIDGE=<a deltaloop-bridge built with --features zenoh>: the same ping-pong over
#      Zenoh (peer to peer, TCP and UDP endpoints, express publishers).
# Needs root and iproute2. Usage: [ZENOH_BRIDGE=…] docs/bench/net.sh [BIN_DIR (target/release)] [HOLD_S (9)]
set -eu
B=${1:-target/release}; HOLD=${2:-9}
T=$(mktemp -d); A=dlbench$$a; Z=dlbench$$b
# iceoryx2 keeps one management segment per root in /dev/shm, under the root's prefix
# (iox2_<FNV-1a 32 of "<root>/">_, docs/protocol.md §14): remove those too.
prefix() { python3 -c "
h = 0x811C9DC5
for b in '$1/'.encode(): h = ((h ^ b) * 0x01000193) & 0xFFFFFFFF
print(f'iox2_{h:08x}_')"; }
cleanup() {
  ip netns del $A 2>/dev/null || true; ip netns del $Z 2>/dev/null || true
  for r in $T/iox-a $T/iox-b; do rm -f /dev/shm/$(prefix $r)*; done
  rm -rf "$T"
}
trap cleanup EXIT
ip netns add $A; ip netns add $Z
ip link add vb$$a netns $A type veth peer name vb$$b netns $Z
ip -n $A addr add 10.77.0.1/30 dev vb$$a; ip -n $A link set vb$$a up; ip -n $A link set lo up
ip -n $Z addr add 10.77.0.2/30 dev vb$$b; ip -n $Z link set vb$$b up; ip -n $Z link set lo up
inA() { ip netns exec $A env DELTALOOP_IOX2_ROOT=$T/iox-a "$@"; }
inZ() { ip netns exec $Z env DELTALOOP_IOX2_ROOT=$T/iox-b "$@"; }
echo "# $(date -u +%FT%TZ) $(git rev-parse --short HEAD 2>/dev/null) $(uname -r), hold $HOLD s"
inZ $B/deltaloop-bridge pong --listen 10.77.0.2:7500 & PONG=$!
sleep 0.3
inA $B/deltaloop-bridge ping --connect 10.77.0.2:7500 --count 33000
kill $PONG; wait $PONG 2>/dev/null || true
if [ -n "${ZENOH_BRIDGE:-}" ]; then
  for ep in tcp/10.77.0.2:7600 udp/10.77.0.2:7601; do
    inZ $ZENOH_BRIDGE zpong --listen $ep > /dev/null 2>&1 & ZP=$!
    sleep 1
    inA $ZENOH_BRIDGE zping --connect $ep --count 33000 2>&1 | tail -1
    kill $ZP; wait $ZP 2>/dev/null || true
  done
fi
row() { # label, run dir
  python3 - "$1" "$2" <<'PY'
import json, sys
s = json.load(open(sys.argv[2] + "/summary.json")); t = s["timing"]["tdc"]
r, c, x = t["round_trip"], t["state_to_controller"], t["controller_compute"]
print(f"{sys.argv[1]}: round trip p50 {r['p50_us']:.1f} p99 {r['p99_us']:.1f} p99.9 {r['p999_us']:.1f} max {r['max_us']:.1f} us;"
      f" state->controller p50 {c['p50_us']:.1f}; compute p50 {x['p50_us']:.1f}; misses {t['deadline_misses']} of {t['ticks']};"
      f" status {s['laws']['tdc']['status']}")
PY
}
remote() { # label, near spin µs, far spin µs
  inZ $B/deltaloop join 10.77.0.1:7447 --spin-us $3 > $T/join.log 2>&1 & J=$!
  inA $B/deltaloop run configs/s1-nominal.toml --law tdc --mode realtime --hold-s $HOLD \
    --controller-remote 10.77.0.1:7447 --link-spin-us $2 --out $T/$1 > $T/run.log 2>&1 || true
  wait $J || true
  row "bridge, $1" $T/$1
}
remote blocking 0 0
remote near-polls 150 0
remote far-polls 0 150
$B/deltaloop run configs/s1-nominal.toml --law tdc --mode realtime --hold-s $HOLD --out $T/local > $T/run.log 2>&1 || true
row "one host, no bridge" $T/local
