"""What `ros2 node list` and `ros2 node info` would show, from DDS alone (no ROS install).

    python examples/ros2/graph.py --domain N [--distro jazzy|humble] [--wait-s 5] [--expect TOPIC]…

A ROS 2 node is not a DDS entity: each participant announces its nodes on `ros_discovery_info`
(rmw_dds_common's ParticipantEntitiesInfo, reliable, transient local), each node with the gids
of its readers and writers. The first 16 bytes of a gid are the endpoint's DDS GUID (12-byte
participant prefix + 4-byte entity id), the key of its DCPSPublication / DCPSSubscription
built-in sample, which carries the topic and type. This joins the two, with ROS names: topic
`rt/a/b` → `/a/b`, type `pkg::msg::dds_::Name_` → `pkg/msg/Name`.

Waits up to `--wait-s` for at least one node and for a publisher of each `--expect` topic (then
until the graph is complete, or stops changing for 0.5 s), and prints on stdout

    {"nodes": [{"name": "/deltaloop", "publishers": [{"topic": "/deltaloop/tdc/joint_states",
      "type": "sensor_msgs/msg/JointState"}, …], "subscribers": […]}, …], "unmatched_gids": 0}

`unmatched_gids`: gids named by a node with no endpoint discovered behind them. Gids are 16 bytes
on Iron and later (`--distro jazzy`, the default) and 24 on Humble (`--distro humble`). Exit 1 if
no node was seen, 2 if an expected topic has no publisher. All DDS traffic stays on loopback (`deltaloop.ros2.participant`).
"""

import argparse
import json
import re
import sys
import time

from cyclonedds.builtin import BuiltinDataReader, BuiltinTopicDcpsPublication, BuiltinTopicDcpsSubscription
from cyclonedds.core import InstanceState, ReadCondition, SampleState, ViewState, WaitSet
from cyclonedds.internal import InvalidSample
from cyclonedds.qos import Policy, Qos
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic

from deltaloop import ros2

_SETTLE_S = 0.5
_DDS_TYPE = re.compile(r"^(\w+)::(msg|srv|action)::dds_::(\w+)_$")


def ros_topic(name: str) -> str:
    return "/" + name[3:] if name.startswith("rt/") else name


def ros_type(name: str) -> str:
    m = _DDS_TYPE.match(name)
    return f"{m[1]}/{m[2]}/{m[3]}" if m else name


def node_name(namespace: str, name: str) -> str:
    return namespace.rstrip("/") + "/" + name


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--domain", type=int, required=True, help="DDS domain id")
    p.add_argument("--distro", choices=sorted(ros2.GID_BYTES), default="jazzy", help="Gid: jazzy 16 bytes, humble 24")
    p.add_argument("--wait-s", type=float, default=5.0, help="longest wait for the first node")
    p.add_argument("--expect", action="append", default=[], metavar="TOPIC",
                   help="wait also for a node publishing this ROS topic (repeatable)")
    a = p.parse_args()

    _, _, ParticipantEntitiesInfo = ros2.graph_types(a.distro)
    other = "humble" if a.distro == "jazzy" else "jazzy"
    dp = ros2.participant(a.domain)
    any_new = SampleState.NotRead | ViewState.Any | InstanceState.Any
    # NoKey: all participants write the one instance; a deep history keeps each one's sample.
    info = DataReader(dp, Topic(dp, ros2.TOPIC_DISCOVERY, ParticipantEntitiesInfo, qos=ros2.QOS_DISCOVERY),
                      qos=Qos(Policy.History.KeepLast(256), base=ros2.QOS_DISCOVERY))
    pubs = BuiltinDataReader(dp, BuiltinTopicDcpsPublication)
    subs = BuiltinDataReader(dp, BuiltinTopicDcpsSubscription)
    ws = WaitSet(dp)
    conds = {r: ReadCondition(r, any_new) for r in (info, pubs, subs)}
    for c in conds.values():
        ws.attach(c)

    participants = {}  # participant gid → its latest ParticipantEntitiesInfo
    endpoints = {}  # GUID (16 bytes) → (is a writer, DDS topic, DDS type)

    def take() -> bool:
        changed = False
        try:
            got = info.take(N=256, condition=conds[info])
        except Exception as e:  # a sample of the other distro's Gid size
            print(f"graph: unreadable ros_discovery_info sample ({e}); is it --distro {other}?", file=sys.stderr)
            got = []
        for s in got:
            if not isinstance(s, InvalidSample):
                participants[bytes(s.gid.data)] = s
                changed = True
        for r, is_writer in ((pubs, True), (subs, False)):
            for s in r.take(N=256, condition=conds[r]):
                key = s.key.bytes
                if s.sample_info.instance_state == InstanceState.Alive:
                    endpoints[key] = (is_writer, s.topic_name, s.type_name)
                else:
                    endpoints.pop(key, None)
                changed = True
        return changed

    def gids():
        return [bytes(g.data)[:16] for pi in participants.values() for n in pi.node_entities_info_seq
                for g in (*n.reader_gid_seq, *n.writer_gid_seq)]

    def published():
        mine = set(gids())
        return {ros_topic(e[1]) for g, e in endpoints.items() if e[0] and g in mine}

    start = time.monotonic()
    last_change = start
    while True:
        if take():
            last_change = time.monotonic()
        now = time.monotonic()
        nodes = sum(len(pi.node_entities_info_seq) for pi in participants.values())
        expected = set(a.expect) <= published()
        if nodes and expected and (all(g in endpoints for g in gids()) or now - last_change >= _SETTLE_S):
            break
        if now - start >= a.wait_s:
            break
        ws.wait(int(min(0.05, max(0.001, a.wait_s - (now - start))) * 1e9))

    out, unmatched = [], 0
    for pi in participants.values():
        for n in pi.node_entities_info_seq:
            sides = {"publishers": set(), "subscribers": set()}
            for side, seq, want_writer in (("publishers", n.writer_gid_seq, True),
                                           ("subscribers", n.reader_gid_seq, False)):
                for g in seq:
                    e = endpoints.get(bytes(g.data)[:16])
                    if e is None or e[0] != want_writer:
                        unmatched += 1
                    else:
                        sides[side].add((ros_topic(e[1]), ros_type(e[2])))
            out.append({"name": node_name(n.node_namespace, n.node_name),
                        **{k: [{"topic": t, "type": ty} for t, ty in sorted(v)] for k, v in sides.items()}})
    out.sort(key=lambda n: n["name"])
    print(json.dumps({"nodes": out, "unmatched_gids": unmatched}, indent=1))
    if not out:
        print(f"graph: no node on {ros2.TOPIC_DISCOVERY} within {a.wait_s:g} s "
              f"(a {other} graph needs --distro {other})", file=sys.stderr)
    missing = sorted(set(a.expect) - published())
    if out and missing:
        print(f"graph: no node publishes {', '.join(missing)} within {a.wait_s:g} s", file=sys.stderr)
    return 1 if not out else 2 if missing else 0


if __name__ == "__main__":
    sys.exit(main())
