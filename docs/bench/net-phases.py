"""Where a tick's round trip goes, from the folders `deltaloop bench net --out DIR` keeps.

    python3 docs/bench/net-phases.py DIR [DIR ...]

For the direct and one-host rows of each DIR, from `<row>/tdc.timing.csv` (CLOCK_MONOTONIC, both
namespaces share it), p50 / p99 / p99.9 in µs of
  deadline -> publish   the plant's work before it stamps and sends the state,
  deadline -> arrival   the reply at the plant (the link's kernel receive stamp on the direct
                        path, the controller's publish stamp on one host): when it acts on the robot,
  deadline -> taken     the plant's own read of the reply,
  publish  -> taken     the round trip `bench net` reports.
Ticks without a reply (missed) are left out.
"""

import csv
import sys


def pct(values, p):
    v = sorted(values)
    return v[min(len(v) - 1, int(p * len(v)))]


def fmt(values):
    return "%5.1f / %5.1f / %6.1f" % (pct(values, 0.5), pct(values, 0.99), pct(values, 0.999))


def phases(path):
    pub, arrival, taken, rtt = [], [], [], []
    for row in csv.DictReader(open(path)):
        if not (row["arrival_ns"] and row["torque_rx_ns"] and row["state_pub_ns"]):
            continue
        dl, pb, tk = int(row["deadline_ns"]), int(row["state_pub_ns"]), int(row["torque_rx_ns"])
        pub.append((pb - dl) / 1e3)
        arrival.append(int(row["arrival_ns"]) / 1e3)  # already relative to the deadline
        taken.append((tk - dl) / 1e3)
        rtt.append((tk - pb) / 1e3)
    return pub, arrival, taken, rtt


def main():
    if len(sys.argv) < 2:
        sys.exit(__doc__)
    print("| run | row | deadline -> publish | deadline -> arrival | deadline -> taken | publish -> taken |")
    print("|---|---|---|---|---|---|")
    for d in sys.argv[1:]:
        for row in ("direct", "one-host"):
            cols = " | ".join(fmt(v) for v in phases(f"{d}/{row}/tdc.timing.csv"))
            print(f"| {d} | {row} | {cols} |")


if __name__ == "__main__":
    main()
