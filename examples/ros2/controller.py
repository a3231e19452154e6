"""The `tdc` law as a ROS 2-style node over plain DDS (cyclonedds, no rclpy): the controller of
`deltaloop run … --controller ros2`.

    python examples/ros2/controller.py --config RUN/config.toml --domain N [--namespace deltaloop]
        [--law tdc] [--state-topic rt/robot_joint_states] [--command-topic rt/robot_joint_commands]
        [--idle-s 5] [--wait-s 60]

It reads the law's reference from `rt/<namespace>/<law>/trajectory` (transient local, so it may
start before or after the run: points[k] is tick k's q_d, q̇_d, q̈_d; the trajectory ends at the
first tick of the hold, which every later tick holds). Only then does it subscribe
to the states, so a robot side that waits for a matched subscriber knows the node is ready. It
answers every robot_joint_states sample (stamp k·Ts; position q_k, velocity q̇_k, effort τᵃ_k)
with one robot_joint_commands sample of the same stamp whose effort is τ_k, in order. The law is
`deltaloop.tdc.Tdc` (shared with examples/python-controller: same operations, same order), so for the
same states it gives the built-in controller's torques bit for bit.

Ends with exit 0 and one line on stderr (`answered N states, first tick A, last tick B`) after
`--idle-s` seconds without a state once one was answered, or on SIGTERM/SIGINT. Exit 1: no
trajectory or no state within `--wait-s`, or a state stamped off the tick grid.
All DDS traffic stays on loopback (`deltaloop.ros2.participant`).
"""

import argparse
import gc
import signal
import sys
import time
import tomllib
from collections import namedtuple

from cyclonedds.core import InstanceState, ReadCondition, SampleState, ViewState, WaitSet
from cyclonedds.pub import DataWriter
from cyclonedds.qos import Policy, Qos
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic

from deltaloop import ros2
from deltaloop.tdc import Tdc  # the law, shared with examples/python-controller

_SLICE_NS = 50_000_000  # longest wait before looking at the clock and the signals
_BATCH = 64  # states taken per take()
# States and commands go through deltaloop.ros2's struct codec and raw write/take: the same bytes
# as cyclonedds's IdlStruct path, ~40 µs less per tick.

Ref = namedtuple("Ref", "q qd qdd")  # tick k of the reference, as Tdc.step reads it
State = namedtuple("State", "q qd tau_applied")  # tick k's state, as Tdc.step reads it


# ---- the node ------------------------------------------------------------------------------------


class Stop(Exception):
    pass


def fail(why: str) -> int:
    print(f"ros2-tdc: {why}", file=sys.stderr)
    return 1


def wait_for(waitset: WaitSet, cond: ReadCondition, deadline: float, stop) -> bool:
    """Blocks until `cond` holds (True) or `deadline` (time.monotonic) passes (False)."""
    while not cond.is_triggered():
        if stop[0]:
            raise Stop
        left = deadline - time.monotonic()
        if left <= 0:
            return False
        waitset.wait(min(_SLICE_NS, int(left * 1e9) + 1))
    return True


def load_reference(traj, ts_ns: int):
    """The trajectory as Refs indexed by tick; raises ValueError if point k is not at k·Ts."""
    refs = []
    for k, p in enumerate(traj.points):
        if ros2.stamp_ns(p.time_from_start) != k * ts_ns:
            at = ros2.stamp_ns(p.time_from_start)
            raise ValueError(f"trajectory point {k} is at {at} ns, not k·Ts = {k * ts_ns} ns")
        refs.append(Ref(tuple(p.positions), tuple(p.velocities), tuple(p.accelerations)))
    return refs


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--config", required=True, help="the run's resolved config (TOML)")
    p.add_argument("--domain", type=int, required=True, help="DDS domain id")
    p.add_argument("--namespace", default="deltaloop")
    p.add_argument("--law", default="tdc", help="whose trajectory to follow (the law is always tdc)")
    p.add_argument("--state-topic", default=ros2.TOPIC_ROBOT_STATES)
    p.add_argument("--command-topic", default=ros2.TOPIC_ROBOT_COMMANDS)
    p.add_argument("--idle-s", type=float, default=5.0, help="exit this long after the last state")
    p.add_argument("--wait-s", type=float, default=60.0, help="longest wait for the trajectory, then the first state")
    a = p.parse_args()

    try:
        with open(a.config, "rb") as f:
            config = tomllib.load(f)
        law = Tdc(config)
    except (OSError, tomllib.TOMLDecodeError) as e:
        return fail(f"cannot read the config {a.config}: {e}")
    except (KeyError, ValueError) as e:
        return fail(f"the config lacks controller constant {e} (pass the resolved config)")
    ts_ns = round(law.ts * 1e9)

    stop = [None]

    def on_signal(signum, _frame):
        stop[0] = signal.Signals(signum).name

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)

    dp = ros2.participant(a.domain)
    traj_name = ros2.topic_prefix(a.namespace, a.law) + "/trajectory"
    traj_topic = Topic(dp, traj_name, ros2.JointTrajectory, qos=ros2.QOS_TRAJECTORY)
    state_topic = Topic(dp, a.state_topic, ros2.JointState, qos=ros2.QOS_ROBOT)
    cmd_topic = Topic(dp, a.command_topic, ros2.JointState, qos=ros2.QOS_ROBOT)
    traj_reader = DataReader(dp, traj_topic, qos=ros2.QOS_TRAJECTORY)
    any_new = SampleState.NotRead | ViewState.Any | InstanceState.Any
    answered, first, last = 0, None, None

    try:
        # The trajectory: the first valid sample (transient local, so also one written before we came).
        traj_cond = ReadCondition(traj_reader, any_new)
        ws = WaitSet(dp)
        ws.attach(traj_cond)
        deadline = time.monotonic() + a.wait_s
        traj = None
        while traj is None:
            if not wait_for(ws, traj_cond, deadline, stop):
                return fail(f"no trajectory on {traj_topic.name} within {a.wait_s:g} s")
            got = traj_reader.take(N=1, condition=traj_cond)
            traj = next((s for s in got if isinstance(s, ros2.JointTrajectory)), None)
        try:
            refs = load_reference(traj, ts_ns)
        except ValueError as e:
            return fail(str(e))
        del traj
        ws.detach(traj_cond)
        print(f"ros2-tdc: {len(refs)} trajectory points from {traj_topic.name}", file=sys.stderr)

        # Only now the state reader and the command writer: once the robot side sees them matched,
        # the node is ready. KeepAll: a state is never dropped here (the law needs every tick, in
        # order), whatever the writer's depth; reliability holds the writer back instead.
        state_reader = DataReader(dp, state_topic, qos=Qos(Policy.History.KeepAll, base=ros2.QOS_ROBOT))
        cmd_writer = DataWriter(dp, cmd_topic, qos=ros2.QOS_ROBOT)

        # The loop: take what came, answer each in order, wait.
        cond = ReadCondition(state_reader, any_new)
        ws.attach(cond)
        step, refs_n = law.step, len(refs)
        encode, decode, take, write = ros2.encode_joint_state, ros2.decode_joint_state, ros2.take_raw, ros2.write_raw
        names, empty = list(ros2.JOINTS), []
        gc.collect()
        gc.disable()  # no collector pauses in the loop (35 000 points are ~10⁵ objects; the loop makes no cycles)
        deadline = time.monotonic() + a.wait_s
        while True:
            samples = take(state_reader, _BATCH)
            if samples:
                for data in samples:
                    s = decode(data)
                    t = s.header.stamp
                    k, rest = divmod(t.sec * 1_000_000_000 + t.nanosec, ts_ns)
                    if rest or k < 0:
                        return fail(f"state at {t.sec} s {t.nanosec} ns: not on a tick (Ts = {ts_ns} ns)")
                    # The trajectory ends at the first tick of the hold: every later tick holds it.
                    if last is not None and k != last + 1:
                        print(f"ros2-tdc: state of tick {k} follows tick {last}", file=sys.stderr)
                    try:
                        tau = step(State(s.position, s.velocity, s.effort), refs[min(k, refs_n - 1)])[0]
                    except IndexError:
                        return fail(f"tick {k}: the state or its trajectory point has fewer than 3 joints")
                    write(cmd_writer, encode(t.sec, t.nanosec, s.header.frame_id, names, empty, empty, tau))
                    answered += 1
                    last = k
                    if first is None:
                        first = k
                deadline = time.monotonic() + a.idle_s
                continue
            if stop[0]:
                break
            if not wait_for(ws, cond, deadline, stop):
                if answered:
                    break
                return fail(f"no state on {a.state_topic} within {a.wait_s:g} s")
    except Stop:
        pass
    if not answered:
        return fail(f"stopped by {stop[0]} before any state")
    print(f"answered {answered} states, first tick {first}, last tick {last}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
