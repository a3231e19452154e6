"""What a Dask task costs beyond its work, measured on a running cluster:

    python -m deltaloop.dask_overhead --scheduler-file scheduler.json [--tasks 400]

- **empty task**: ``--tasks`` no-op tasks submitted at once (the resources of a sweep task,
  ``CPU=1``); wall time per task × worker threads = scheduler and transport cost per task.
- **round trip**: one no-op task at a time, submit to result (the latency a lone task sees).

What a point adds on top (the ``deltaloop`` process, the plan check, the temporary folder) shows
in ``python -m deltaloop.dask … --batch 1`` against ``--batch 50``: see docs/guide/cluster.md.
Medians of ``--repeats`` measurements are printed.
"""

from __future__ import annotations

import argparse
import statistics
import time


def _noop(i):
    return i


def empty_task_s(client, tasks: int) -> float:
    """Seconds of cluster time per no-op task (wall / tasks × worker threads)."""
    threads = sum(w["nthreads"] for w in client.scheduler_info(n_workers=-1)["workers"].values())
    t0 = time.perf_counter()
    fs = client.map(_noop, range(tasks), resources={"CPU": 1}, pure=False)
    client.gather(fs)
    return (time.perf_counter() - t0) / tasks * threads


def round_trip_s(client, n: int = 20) -> float:
    ts = []
    for i in range(n):
        t0 = time.perf_counter()
        client.submit(_noop, i, resources={"CPU": 1}, pure=False).result()
        ts.append(time.perf_counter() - t0)
    return statistics.median(ts)


def main(argv=None) -> int:
    from distributed import Client

    ap = argparse.ArgumentParser(prog="python -m deltaloop.dask_overhead")
    g = ap.add_mutually_exclusive_group(required=True)
    g.add_argument("--scheduler")
    g.add_argument("--scheduler-file")
    ap.add_argument("--tasks", type=int, default=400)
    ap.add_argument("--repeats", type=int, default=5)
    a = ap.parse_args(argv)
    with Client(a.scheduler or None, scheduler_file=a.scheduler_file) as client:
        client.wait_for_workers(1, timeout=60)
        info = client.scheduler_info(n_workers=-1)["workers"].values()
        print(f"workers: {len(info)}, threads: {sum(w['nthreads'] for w in info)}")
        empty = statistics.median(empty_task_s(client, a.tasks) for _ in range(a.repeats))
        rt = statistics.median(round_trip_s(client) for _ in range(a.repeats))
        print(f"empty task, {a.tasks} at once: {empty * 1e3:.2f} ms of worker time per task (median of {a.repeats})")
        print(f"round trip of one task: {rt * 1e3:.2f} ms (median of {a.repeats} × 20)")
    return 0


if __name__ == "__main__":
    from deltaloop.dask_overhead import main as _main

    raise SystemExit(_main())
