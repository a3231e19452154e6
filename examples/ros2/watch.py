"""Records what a `deltaloop run … --ros2` publishes for one law, as JSON lines, over plain DDS.

    python examples/ros2/watch.py --domain N --out FILE [--namespace deltaloop] [--law tdc]
        [--idle-s 5] [--wait-s 60] [--arrival]

Subscribes to the law's `rt/<namespace>/<law>/{joint_states,reference,trajectory}` and to the
shared `rt/tf`, `rt/clock`, `rt/diagnostics` and `rt/rosout`, and writes one line per sample:

    {"topic": "rt/deltaloop/tdc/joint_states", "sec": 0, "nanosec": 3000000, "frame_id": "base",
     "name": ["joint_1", "joint_2", "joint_3"], "position": ["0x1.0p-3", …], "velocity": […], "effort": […]}

Every float64 is written as its `float.hex()` string, so it reads back exactly: `float.fromhex(s)`.
With `--arrival` each line also has `arrival_ns`: when the watcher took the sample, CLOCK_MONOTONIC
ns (the clock of a run's `<law>.timing.csv`, on the same host).
The other types: trajectory {sec, nanosec, frame_id, joint_names, points: [{positions,
velocities, accelerations, effort, sec, nanosec}]} (one line for the whole trajectory); tf
{transforms: [{sec, nanosec, frame_id, child_frame_id, translation: [x, y, z], rotation:
[x, y, z, w]}]}; clock {sec, nanosec}; diagnostics {sec, nanosec, frame_id, status: [{level, name,
message, hardware_id, values: {key: value}}]}; rosout {sec, nanosec, level, name, msg, file,
function, line}. Lines are in arrival order per topic; across topics, in the order they were taken.

Joint topics are read reliable with a KeepLast(1000) history, so nothing is dropped at the
publishing rate; the trajectory and rosout are transient local (a late watcher still gets them).
The file is line-buffered: a killed watcher leaves every line it had taken. Ends (exit 0) after
`--idle-s` seconds without a sample once one came, or on SIGTERM/SIGINT (after taking what is
queued); exit 1 if nothing came within `--wait-s` (0: wait for ever). All DDS traffic stays on
loopback (`deltaloop.ros2.participant`).
"""

import argparse
import json
import signal
import sys
import time

from cyclonedds.core import InstanceState, ReadCondition, SampleState, ViewState, WaitSet
from cyclonedds.internal import InvalidSample
from cyclonedds.qos import Policy, Qos
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic

from deltaloop import ros2

_SLICE_NS = 50_000_000  # longest wait before looking at the clock and the signals
_BATCH = 256


def hexes(xs):
    return [float(x).hex() for x in xs]


def joint_state(s):
    t = s.header.stamp
    return {"sec": t.sec, "nanosec": t.nanosec, "frame_id": s.header.frame_id, "name": list(s.name),
            "position": hexes(s.position), "velocity": hexes(s.velocity), "effort": hexes(s.effort)}


def trajectory(s):
    t = s.header.stamp
    return {"sec": t.sec, "nanosec": t.nanosec, "frame_id": s.header.frame_id, "joint_names": list(s.joint_names),
            "points": [{"positions": hexes(p.positions), "velocities": hexes(p.velocities),
                        "accelerations": hexes(p.accelerations), "effort": hexes(p.effort),
                        "sec": p.time_from_start.sec, "nanosec": p.time_from_start.nanosec} for p in s.points]}


def tf(s):
    out = []
    for ts in s.transforms:
        tr, rot = ts.transform.translation, ts.transform.rotation
        out.append({"sec": ts.header.stamp.sec, "nanosec": ts.header.stamp.nanosec, "frame_id": ts.header.frame_id,
                    "child_frame_id": ts.child_frame_id, "translation": hexes((tr.x, tr.y, tr.z)),
                    "rotation": hexes((rot.x, rot.y, rot.z, rot.w))})
    return {"transforms": out}


def clock(s):
    return {"sec": s.clock.sec, "nanosec": s.clock.nanosec}


def diagnostics(s):
    t = s.header.stamp
    return {"sec": t.sec, "nanosec": t.nanosec, "frame_id": s.header.frame_id,
            "status": [{"level": st.level, "name": st.name, "message": st.message, "hardware_id": st.hardware_id,
                        "values": {kv.key: kv.value for kv in st.values}} for st in s.status]}


def rosout(s):
    return {"sec": s.stamp.sec, "nanosec": s.stamp.nanosec, "level": s.level, "name": s.name, "msg": s.msg,
            "file": s.file, "function": s.function, "line": s.line}


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--domain", type=int, required=True, help="DDS domain id")
    p.add_argument("--namespace", default="deltaloop")
    p.add_argument("--law", default="tdc")
    p.add_argument("--out", required=True, help="the JSON-lines file to write")
    p.add_argument("--idle-s", type=float, default=5.0, help="exit this long after the last sample")
    p.add_argument("--wait-s", type=float, default=60.0, help="longest wait for the first sample (0: for ever)")
    p.add_argument("--arrival", action="store_true", help="add arrival_ns (CLOCK_MONOTONIC) to each line")
    a = p.parse_args()

    stop = [None]

    def on_signal(signum, _frame):
        stop[0] = signal.Signals(signum).name

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)

    dp = ros2.participant(a.domain)
    prefix = ros2.topic_prefix(a.namespace, a.law)
    deep = Policy.History.KeepLast(1000)
    # (topic, type, the writer's QoS, reader QoS, to JSON). Every sample is decoded by
    # cyclonedds's own deserializer (not deltaloop.ros2's fast codec): an independent reading.
    plan = [
        (prefix + "/joint_states", ros2.JointState, ros2.QOS_JOINT, Qos(deep, base=ros2.QOS_JOINT), joint_state),
        (prefix + "/reference", ros2.JointState, ros2.QOS_JOINT, Qos(deep, base=ros2.QOS_JOINT), joint_state),
        (prefix + "/trajectory", ros2.JointTrajectory, ros2.QOS_TRAJECTORY,
         Qos(Policy.History.KeepLast(10), base=ros2.QOS_TRAJECTORY), trajectory),
        (ros2.TOPIC_TF, ros2.TFMessage, ros2.QOS_TF, Qos(deep, base=ros2.QOS_TF), tf),
        (ros2.TOPIC_CLOCK, ros2.Clock, ros2.QOS_CLOCK, Qos(deep, base=ros2.QOS_CLOCK), clock),
        (ros2.TOPIC_DIAGNOSTICS, ros2.DiagnosticArray, ros2.QOS_DIAGNOSTICS,
         Qos(deep, base=ros2.QOS_DIAGNOSTICS), diagnostics),
        (ros2.TOPIC_ROSOUT, ros2.Log, ros2.QOS_ROSOUT, Qos(deep, base=ros2.QOS_ROSOUT), rosout),
    ]
    ws = WaitSet(dp)
    readers = []
    for name, typ, topic_qos, reader_qos, to_json in plan:
        r = DataReader(dp, Topic(dp, name, typ, qos=topic_qos), qos=reader_qos)
        cond = ReadCondition(r, SampleState.NotRead | ViewState.Any | InstanceState.Any)
        ws.attach(cond)
        readers.append((name, r, cond, to_json))

    counts = {name: 0 for name, *_ in readers}
    with open(a.out, "w", buffering=1) as out:  # line-buffered

        def drain() -> int:
            n = 0
            for name, r, cond, to_json in readers:
                while True:
                    got = r.take(N=_BATCH, condition=cond)
                    batch = [to_json(s) for s in got if not isinstance(s, InvalidSample)]
                    if a.arrival:
                        now = time.monotonic_ns()
                        for rec in batch:
                            rec["arrival_ns"] = now
                    for rec in batch:
                        out.write(json.dumps({"topic": name, **rec}, separators=(",", ":")) + "\n")
                    n += len(batch)
                    counts[name] += len(batch)
                    if len(batch) < _BATCH:
                        break
            return n

        first = None
        last = time.monotonic()
        while not stop[0]:
            if drain():
                last = time.monotonic()
                first = first or last
                continue
            now = time.monotonic()
            if first is not None and now - last >= a.idle_s:
                break
            if first is None and a.wait_s > 0 and now - last >= a.wait_s:
                print(f"watch: nothing on {prefix}/* or the shared topics within {a.wait_s:g} s", file=sys.stderr)
                return 1
            limit = a.idle_s if first is not None else (a.wait_s or 3600.0)
            ws.wait(max(1, min(_SLICE_NS, int((last + limit - now) * 1e9))))
        drain()
    total = sum(counts.values())
    print(f"watch: {total} samples to {a.out}: " + ", ".join(f"{k} {v}" for k, v in counts.items() if v)
          + (f" (stopped by {stop[0]})" if stop[0] else ""), file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
