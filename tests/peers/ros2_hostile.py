"""A tdc node over DDS that also sends what deltaloop must refuse (tests/e2e/ros2.rs): before its
answer to tick 5 a command with the joints in another order, to tick 6 one with two efforts, to
tick 7 one with a NaN, to tick 8 tick 7's stamp again, and to tick 9 a valid-looking command from a
second writer. Every answer itself is the tdc law's, so the run stays the built-in's.
With `--stale`, it answers every state with the next tick's stamp instead: every command is
refused as stale, and the run ends at tick 0.

    python tests/peers/ros2_hostile.py --config RUN/config.toml --domain N [--idle-s 2] [--stale]
"""

import argparse
import sys
import time
import tomllib
from collections import namedtuple

from cyclonedds.pub import DataWriter
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic

from deltaloop import ros2
from deltaloop.tdc import Tdc

Ref = namedtuple("Ref", "q qd qdd")
State = namedtuple("State", "q qd tau_applied")


def main():
    p = argparse.ArgumentParser()
    p.add_argument("--config", required=True)
    p.add_argument("--domain", type=int, required=True)
    p.add_argument("--idle-s", type=float, default=2.0, help="exit this long after the last state")
    p.add_argument("--stale", action="store_true", help="stamp every answer with the next tick's stamp")
    a = p.parse_args()
    cfg = tomllib.load(open(a.config, "rb"))
    ts_ns = round(float(cfg["loop"]["ts_s"]) * 1e9)
    law = Tdc(cfg)
    dp = ros2.participant(a.domain)
    traj_reader = DataReader(dp, Topic(dp, ros2.topic_prefix("deltaloop", "tdc") + "/trajectory", ros2.JointTrajectory,
                                       qos=ros2.QOS_TRAJECTORY), qos=ros2.QOS_TRAJECTORY)
    traj = None
    until = time.monotonic() + 30
    while traj is None and time.monotonic() < until:
        for t in traj_reader.take(N=1):
            traj = t
        time.sleep(0.01)
    if traj is None:
        print("ros2_hostile: no trajectory", file=sys.stderr)
        return 1
    refs = [Ref(pt.positions, pt.velocities, pt.accelerations) for pt in traj.points]
    topic = Topic(dp, ros2.TOPIC_ROBOT_COMMANDS, ros2.JointState, qos=ros2.QOS_ROBOT)
    main_writer = DataWriter(dp, topic, qos=ros2.QOS_ROBOT)
    second = DataWriter(dp, topic, qos=ros2.QOS_ROBOT)
    # Both writers discovered before deltaloop sees the node (it waits for the states' reader).
    time.sleep(1.0)
    states = DataReader(dp, Topic(dp, ros2.TOPIC_ROBOT_STATES, ros2.JointState, qos=ros2.QOS_ROBOT), qos=ros2.QOS_ROBOT)

    def command(t, effort, names=ros2.JOINTS):
        return ros2.JointState(header=ros2.Header(stamp=t, frame_id="base"), name=list(names), effort=list(effort))

    answered, idle = 0, time.monotonic() + 30
    while time.monotonic() < idle:
        got = [s for s in states.take(N=64) if isinstance(s, ros2.JointState)]
        if not got:
            time.sleep(0.0002)
            continue
        for s in got:
            t = s.header.stamp
            k = (t.sec * 1_000_000_000 + t.nanosec) // ts_ns
            tau = law.step(State(s.position, s.velocity, s.effort), refs[min(k, len(refs) - 1)])[0]
            if a.stale:
                main_writer.write(command(ros2.stamp(k + 1, ts_ns), tau))
            elif k == 5:
                main_writer.write(command(t, tau, ["joint_1", "joint_3", "joint_2"]))
            elif k == 6:
                main_writer.write(command(t, tau[:2]))
            elif k == 7:
                main_writer.write(command(t, [tau[0], float("nan"), tau[2]]))
            elif k == 8:
                main_writer.write(command(ros2.stamp(7, ts_ns), tau))
            elif k == 9:
                second.write(command(t, [0.0, 0.0, 0.0]))
            if not a.stale:
                main_writer.write(command(t, tau))
            answered += 1
        idle = time.monotonic() + a.idle_s
    print(f"ros2_hostile: answered {answered} states", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
