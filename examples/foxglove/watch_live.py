"""Watches `deltaloop top --foxglove` as Foxglove does: connects to its WebSocket server
(Foxglove's WebSocket protocol, subprotocol `foxglove.sdk.v1`), subscribes to every channel it
advertises, and decodes what comes: joint states (CDR) with mcap-ros2-support's decoder, the
rest as JSON. Prints one line of counts per topic, and writes the joint states it got as CSV
(t_ns, then the bits of q, q̇ and τᵃ of each joint as integers) so that a test can compare them with
the run's trace.csv.

    target/python-venv/bin/python examples/foxglove/watch_live.py ws://127.0.0.1:8765 SECONDS [OUT.csv]

Stops after SECONDS, or when the server closes (the run ended).
"""

import csv
import json
import struct
import sys
import time
from collections import Counter

from mcap.records import Schema
from mcap_ros2.decoder import DecoderFactory
from websockets.exceptions import ConnectionClosed
from websockets.sync.client import connect


def bits(x):
    """The IEEE-754 bits of a double, as an integer (exact, and easy to compare anywhere)."""
    return struct.unpack("<Q", struct.pack("<d", x))[0]


def main():
    url, seconds = sys.argv[1], float(sys.argv[2])
    out = sys.argv[3] if len(sys.argv) > 3 else None
    cdr = DecoderFactory()
    subs, counts, rows = {}, Counter(), []
    deadline = time.monotonic() + seconds
    with connect(url, subprotocols=["foxglove.sdk.v1"], max_size=None) as ws:
        next_sub = 1
        try:
            while time.monotonic() < deadline:
                try:
                    msg = ws.recv(timeout=max(deadline - time.monotonic(), 0.01))
                except TimeoutError:
                    break
                if isinstance(msg, str):
                    m = json.loads(msg)
                    if m.get("op") != "advertise":
                        continue
                    new = []
                    for ch in m["channels"]:
                        decode = json.loads
                        if ch["encoding"] == "cdr":
                            schema = Schema(id=0, name=ch["schemaName"], encoding="ros2msg",
                                            data=ch["schema"].encode())
                            decode = cdr.decoder_for("cdr", schema)
                        subs[next_sub] = (ch["topic"], decode)
                        new.append({"id": next_sub, "channelId": ch["id"]})
                        next_sub += 1
                    ws.send(json.dumps({"op": "subscribe", "subscriptions": new}))
                    continue
                if msg[0] != 1:  # only message data
                    continue
                sub, t_ns = struct.unpack_from("<IQ", msg, 1)
                topic, decode = subs[sub]
                value = decode(msg[13:])
                counts[topic] += 1
                if topic.endswith("/joint_states"):
                    rows.append([t_ns] + [bits(x) for f in ("position", "velocity", "effort")
                                          for x in getattr(value, f)])
        except ConnectionClosed:
            pass
    for topic in sorted(counts):
        print(f"{topic} {counts[topic]}")
    if out:
        with open(out, "w", newline="") as f:
            csv.writer(f).writerows(rows)


if __name__ == "__main__":
    main()
