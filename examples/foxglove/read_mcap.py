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


def whole_rows(path):
    """The rows of a csv file as dicts, a line at a time, without a last line a kill cut short
    (no newline yet)."""
    with open(path, newline="") as f:
        yield from csv.DictReader(line for line in f if line.endswith("\n"))


def check_timing(law, path, timing, truncated):
    """The timing channel against `<law>.timing.csv` (process runs), row for row by tick: every
    stamp and flag equal, and round_trip_ns = torque_rx_ns - state_pub_ns. A file cut short, or a
    csv cut short by the same kill, is compared on the ticks both hold."""
    if not path.is_file():
        if timing:
            sys.exit(f"{law}: {len(timing)} timing messages and no {path.name}")
        return
    want = {int(r["k"]): r for r in whole_rows(path)}
    have = {m["k"]: m for _, m in timing}
    if len(have) != len(timing):
        sys.exit(f"{law}: a tick twice on the timing channel")
    if not truncated and set(have) != set(want):
        sys.exit(f"{law}: timing channel ticks {len(have)} != {path.name} rows {len(want)}")
    both = set(have) & set(want)
    if truncated and len(both) < min(len(have), len(want)) - 1:
        sys.exit(f"{law}: timing channel and {path.name} share only {len(both)} ticks")
    for k in sorted(both):
        m, r = have[k], want[k]
        for col, cell in r.items():
            if m[col] != (None if cell == "" else int(cell)):
                sys.exit(f"{law} tick {k}: timing {col} {m[col]} != {path.name} {cell!r}")
        rx, tx = m["torque_rx_ns"], m["state_pub_ns"]
        rt = None if rx is None or tx is None else max(rx - tx, 0)
        if m["round_trip_ns"] != rt:
            sys.exit(f"{law} tick {k}: round_trip_ns {m['round_trip_ns']} != {rt}")


def main():
    run = Path(sys.argv[1])
    path = Path(sys.argv[2]) if len(sys.argv) > 2 else run / "run.mcap"
    trace_path = Path(sys.argv[3]) if len(sys.argv) > 3 else run / "trace.csv"
    rows = defaultdict(list)
    for r in whole_rows(trace_path):
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
        check_timing(law, run / f"{law}.timing.csv", timing, truncated)
        print(f"{law} rows={len(trace)} joint_states={len(joints)} control={len(control)} "
              f"scene={len(scene)} timing={len(timing)} events={len(events)} "
              f"last_event={events[-1][1]['message'] if events else ''!r}")
    print(f"reference_path={len(got['/reference_path']['msgs'])}")


if __name__ == "__main__":
    main()
