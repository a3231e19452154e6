"""Reads a `deltaloop export --mcap` file back with the MCAP readers of PyPI (`mcap`,
`mcap-ros2-support`) and compares it with the run's trace.csv, row for row, bit for bit:
joint states (CDR) against q, qdot, tau_applied; the control channel (JSON) against every other
trace column. Prints one line of counts per law; exits 1 on the first difference.

    target/python-venv/bin/python examples/foxglove/read_mcap.py RUN_DIR [FILE [TRACE]]

A file cut short (a run killed while it wrote `<law>.mcap`) is read up to its last whole record,
and compared with the rows of TRACE (default RUN_DIR/trace.csv; a killed run's rows are in
`trace.<law>.part`) it has: `truncated` is printed then.
"""

import csv
import json
import math
import struct
import sys
from collections import defaultdict
from pathlib import Path

from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.records import Channel, Message, Schema
from mcap.stream_reader import StreamReader
from mcap_ros2.decoder import DecoderFactory


def decoded_messages(path):
    """(topic, log_time, decoded) of every message, and whether the file was cut short: JSON
    channels through `json`, CDR ones through mcap-ros2-support's decoder."""
    cdr = DecoderFactory()

    def decode(schema, channel, data):
        if channel.message_encoding == "json":
            return json.loads(data)
        return cdr.decoder_for(channel.message_encoding, schema)(data)

    try:
        with open(path, "rb") as f:
            out = [
                (channel.topic, message.log_time, decode(schema, channel, message.data))
                for schema, channel, message in make_reader(f).iter_messages()
            ]
            return out, False
    except (McapError, EOFError, struct.error):
        pass
    # No summary or footer: read the records in order up to the first one cut off.
    schemas, channels, out = {}, {}, []
    with open(path, "rb") as f:
        try:
            for r in StreamReader(f).records:
                if isinstance(r, Schema):
                    schemas[r.id] = r
                elif isinstance(r, Channel):
                    channels[r.id] = r
                elif isinstance(r, Message):
                    ch = channels[r.channel_id]
                    out.append((ch.topic, r.log_time, decode(schemas.get(ch.schema_id), ch, r.data)))
        except (McapError, EOFError, struct.error):
            pass
    return out, True


def same(a, b):
    """Bit for bit, NaN equal to NaN; None (an empty cell) only to None."""
    if a is None or b is None:
        return a is None and b is None
    return a == b or (math.isnan(a) and math.isnan(b))


def main():
    run = Path(sys.argv[1])
    path = Path(sys.argv[2]) if len(sys.argv) > 2 else run / "run.mcap"
    trace_path = Path(sys.argv[3]) if len(sys.argv) > 3 else run / "trace.csv"
    rows = defaultdict(list)
    with open(trace_path, newline="") as f:
        for r in csv.DictReader(f):
            rows[r["law"]].append(r)
    num = lambda s: None if s == "" else float(s)
    got = defaultdict(lambda: defaultdict(list))
    messages, truncated = decoded_messages(path)
    for topic, t, decoded in messages:
        got[topic]["msgs"].append((t, decoded))
    if truncated:
        print("truncated")
    for law, trace in rows.items():
        if truncated and f"/{law}/joint_states" not in got:
            continue  # a law the cut file never reached
        joints = got[f"/{law}/joint_states"]["msgs"]
        control = got[f"/{law}/control"]["msgs"]
        scene = got[f"/{law}/scene"]["msgs"]
        if truncated:
            # What the cut file holds is a prefix of the run; the trace part may hold more.
            n = min(len(joints), len(control), len(trace))
            joints, control, trace = joints[:n], control[:n], trace[:n]
        if not (len(joints) == len(control) == len(trace)):
            sys.exit(f"{law}: {len(joints)} joint states, {len(control)} control messages, {len(trace)} rows")
        for r, (t, js), (tc, c) in zip(trace, joints, control):
            k = int(r["k"])
            if js.name != ["joint_1", "joint_2", "joint_3"] or t != tc:
                sys.exit(f"{law} tick {k}: names {js.name} or stamps {t} {tc}")
            for field, col in (("position", "q"), ("velocity", "qdot"), ("effort", "tau_applied")):
                want = [num(r[f"{col}_{j}"]) for j in (1, 2, 3)]
                have = list(getattr(js, field))
                if not all(same(a, b) for a, b in zip(have, want)):
                    sys.exit(f"{law} tick {k}: {field} {have} != trace {want}")
            for col in ("q_des", "e", "tau", "s", "n_hat", "n_true"):
                want = [num(r[f"{col}_{j}"]) for j in (1, 2, 3)]
                if not all(same(a, b) for a, b in zip(c[col], want)):
                    sys.exit(f"{law} tick {k}: {col} {c[col]} != trace {want}")
            arrival = None if r["arrival_ns"] == "" else int(r["arrival_ns"])
            if (c["k"], c["reply"], c["drives"], c["arrival_ns"]) != (k, r["reply"], r["drives"], arrival):
                sys.exit(f"{law} tick {k}: {c} against the trace row")
        events = got[f"/{law}/events"]["msgs"]
        timing = got[f"/{law}/timing"]["msgs"]
        print(f"{law} rows={len(trace)} joint_states={len(joints)} control={len(control)} "
              f"scene={len(scene)} timing={len(timing)} events={len(events)} "
              f"last_event={events[-1][1]['message'] if events else ''!r}")
    print(f"reference_path={len(got['/reference_path']['msgs'])}")


if __name__ == "__main__":
    main()
