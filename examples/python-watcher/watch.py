"""Watch a live deltaloop run from outside, read only, through its spare subscriber slot.

    python examples/python-watcher/watch.py [RUN_ID_PREFIX] [--wait S]

Attaches to the run's `telemetry` service (docs/protocol.md §3: one subscriber slot and one node
are kept spare for exactly this), prints one line per second — ticks so far, the tick rate, misses,
and the round trip (state published -> torque received by the plant) of that second — and a last
line when the run is over. It never publishes and never blocks the loop: when it falls behind,
iceoryx2 drops its oldest samples (safe overflow), not the run's.
"""

import argparse
import re
import statistics
import sys
import time

import iceoryx2 as iox2

from deltaloop import services
from deltaloop.wire import TEL_MISSED, TelemetryMsg

_TELEMETRY = re.compile(r'data: "deltaloop/([^/"]+)/telemetry"')


def live_runs(prefix: str) -> list[str]:
    """Run ids with a live `telemetry` service whose id starts with `prefix`."""
    names = (str(s.name()) for s in iox2.Service.list(iox2.config.default(), iox2.ServiceType.Ipc))
    return sorted({m.group(1) for n in names if (m := _TELEMETRY.search(n)) and m.group(1).startswith(prefix)})


def supervisor_alive(run_id: str) -> bool:
    """Whether the run's supervisor node is still alive (the run is not over)."""
    me = f'"deltaloop-supervisor-{run_id}"'
    return any(
        type(n).__name__ == "Alive" and n[0].details is not None and me in str(n[0].details.name)
        for n in iox2.Node.list(iox2.ServiceType.Ipc, iox2.config.default())
    )


def find_run(prefix: str, wait_s: float) -> str:
    deadline = time.monotonic() + wait_s
    while True:
        runs = live_runs(prefix)
        if len(runs) == 1:
            return runs[0]
        if len(runs) > 1:
            sys.exit(f"watch: {len(runs)} live runs match `{prefix}`: {', '.join(runs)}; give more of the id")
        if time.monotonic() > deadline:
            sys.exit(f"watch: no live run matches `{prefix}` after {wait_s:g} s")
        time.sleep(0.05)


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("run", nargs="?", default="", help="the run id, or its start (default: the only live run)")
    p.add_argument("--wait", type=float, default=0.0, help="seconds to wait for the run to appear")
    a = p.parse_args()
    iox2.set_log_level_from_env_or(iox2.LogLevel.Error)
    run_id = find_run(a.run, a.wait)

    cfg = iox2.config.default()
    # A guest: never clean up anyone's nodes (the supervisor owns the run's resources).
    cfg.global_cfg.node.cleanup_dead_nodes_on_creation = False
    cfg.global_cfg.node.cleanup_dead_nodes_on_destruction = False
    cfg.global_cfg.service.cleanup_dead_nodes_on_open = False
    node = (
        iox2.NodeBuilder.new()
        .name(iox2.NodeName.new(f"deltaloop-watcher-{run_id}"))
        .config(cfg)
        .create(iox2.ServiceType.Ipc)
    )
    name = f"deltaloop/{run_id}/telemetry"
    try:
        service = node.service_builder(iox2.ServiceName.new(name)).publish_subscribe(TelemetryMsg).open()
    except Exception as e:  # noqa: BLE001 - the run ended in between, or another wire version
        sys.exit(f"watch: {services.open_error(name, TelemetryMsg, e, 'watcher')}")
    telemetry = service.subscriber_builder().buffer_size(8192).create()
    print(f"watching run {run_id}", flush=True)

    seen = misses = 0
    last_tick = None
    quiet_since = time.monotonic()
    while True:
        t_end = time.monotonic() + 1.0
        round_trips = []
        while time.monotonic() < t_end:
            got = False
            while (smp := telemetry.receive()) is not None:
                m = smp.payload().contents
                got = True
                seen += 1
                last_tick = m.tick
                misses += bool(m.flags & TEL_MISSED)
                if m.t_torque_rx_ns > m.t_state_pub_ns > 0:
                    round_trips.append((m.t_torque_rx_ns - m.t_state_pub_ns) / 1e3)
            if got:
                quiet_since = time.monotonic()
            elif time.monotonic() - quiet_since > 0.2 and not supervisor_alive(run_id):
                print(f"run {run_id} is over: watched {seen} ticks (last tick {last_tick}), {misses} missed", flush=True)
                return 0
            time.sleep(0.01)
        if len(round_trips) >= 2:
            q = statistics.quantiles(round_trips, n=100, method="inclusive")
            rt = f"round trip p50 {q[49]:.1f} µs  p99 {q[98]:.1f} µs  max {max(round_trips):.1f} µs"
        else:
            rt = "no replies this second"
        print(f"tick {last_tick}  +{len(round_trips)} replies/s  misses {misses}  {rt}", flush=True)


if __name__ == "__main__":
    sys.exit(main())
