"""Run a deltaloop sweep on a Dask cluster.

    python -m deltaloop.dask configs/delay-sweep.toml --scheduler tcp://10.0.0.5:8786 --out runs/sweep
    python -m deltaloop.dask configs/delay-sweep.toml --slurm configs/slurm.toml --out runs/sweep

The driver asks the local ``deltaloop`` for the plan (``deltaloop sweep plan FILE --json``), submits
one task per batch of points, appends each batch's rows to its shard folder ``OUT.shard`` as they
arrive, and at the end runs ``deltaloop sweep merge`` on it: the same ``sweep.csv``, ``sweep.json``, report and
plots as ``deltaloop sweep FILE`` on one machine.

Each task runs ``deltaloop sweep run`` on its worker, in a temporary folder, from a copy of the
sweep and its base that travels with the task (workers need the binary, not the config files).
What a point needs is declared as Dask worker resources: ``CPU`` (1 per inproc or lockstep point,
2 per realtime point) and ``RT`` (a realtime point pins its processes to fixed cores, so one per
worker at a time). Start workers with ``--nthreads N --resources "CPU=N,RT=1"``.

A worker that dies mid-point loses nothing: the scheduler re-runs its tasks elsewhere. A task that
fails is retried (a failed batch point by point); a point that fails the same way twice is
reported, and the rest of the sweep finishes; the merged report then lists it as missing.
"""

from __future__ import annotations

import argparse
import io
import json
import os
import shutil
import subprocess
import sys
import tarfile
import tempfile
import time
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

#: Files of a shard folder a task sends back (``points/`` travels as a tar archive).
SHARD_FILES = ("shard.json", "sweep.csv", "sweep.toml", "base.toml")


def default_deltaloop() -> str:
    """The ``deltaloop`` binary: ``$DELTALOOP``, else ``deltaloop`` on ``PATH``."""
    return os.environ.get("DELTALOOP", "deltaloop")


#: Tells a ``deltaloop`` child which process is its parent: it then stops (as on SIGTERM) when
#: that process dies, e.g. a Dask worker killed with SIGKILL, instead of running on as an orphan.
PARENT_PID_ENV = "DELTALOOP_PARENT_PID"


def run_deltaloop(cmd: list[str], **kwargs) -> subprocess.CompletedProcess:
    """``subprocess.run(cmd, capture_output=True, text=True)`` for a ``deltaloop`` command that
    ends when this process dies (``DELTALOOP_PARENT_PID``; not inherited by its own children)."""
    env = dict(kwargs.pop("env", None) or os.environ)
    env[PARENT_PID_ENV] = str(os.getpid())
    return subprocess.run(cmd, capture_output=True, text=True, env=env, **kwargs)


def plan(sweep_file: str | os.PathLike, deltaloop: str | None = None) -> dict:
    """``deltaloop sweep plan FILE --json``: the sweep and base as TOML text, the plan hash, and
    every point (``index``, ``id``, ``label``, ``mode``, ``cpus``)."""
    exe = deltaloop or default_deltaloop()
    p = run_deltaloop([exe, "sweep", "plan", str(sweep_file), "--json"])
    if p.returncode != 0:
        raise SweepError(p.stderr.strip() or f"{exe} sweep plan failed ({p.returncode})")
    return json.loads(p.stdout)


class SweepError(RuntimeError):
    """A sweep that could not run, or points that failed (the message names them)."""


def ranges_text(indices: list[int]) -> str:
    """``[3, 7, 8, 9]`` -> ``"3,7-9"`` (a ``--points`` value)."""
    out, i = [], 0
    while i < len(indices):
        j = i
        while j + 1 < len(indices) and indices[j + 1] == indices[j] + 1:
            j += 1
        out.append(str(indices[i]) if i == j else f"{indices[i]}-{indices[j]}")
        i = j + 1
    return ",".join(out)


def batches(points: list[dict], size: int) -> list[list[int]]:
    """Consecutive points in batches of at most ``size``; a realtime point always alone."""
    out: list[list[int]] = []
    cur: list[int] = []
    for p in points:
        if p["mode"] == "realtime":
            if cur:
                out.append(cur)
                cur = []
            out.append([p["index"]])
            continue
        cur.append(p["index"])
        if len(cur) >= size:
            out.append(cur)
            cur = []
    if cur:
        out.append(cur)
    return out


def resources_for(points: list[dict], indices: list[int]) -> dict:
    """The worker resources a batch holds while it runs."""
    rt = any(points[i]["mode"] == "realtime" for i in indices)
    return {"CPU": 2, "RT": 1} if rt else {"CPU": 1}


def run_points(spec: dict) -> dict:
    """The task: runs ``spec["indices"]`` with ``deltaloop sweep run`` in a temporary folder on
    this worker and returns the shard's files. Raises on any failure of the run itself (a point
    that diverged or could not be configured is a row, not a failure)."""
    t0 = time.monotonic()
    try:
        from distributed import get_worker

        worker = get_worker().address
    except (ImportError, ValueError):
        worker = "local"
    with tempfile.TemporaryDirectory(prefix="deltaloop-task-") as tmp:
        tmp = Path(tmp)
        (tmp / "sweep.toml").write_text(spec["sweep_toml"])
        (tmp / "base.toml").write_text(spec["base_toml"])
        out = tmp / "shard"
        cmd = [
            spec["deltaloop"], "sweep", "run", str(tmp / "sweep.toml"),
            "--base", str(tmp / "base.toml"),
            "--points", ranges_text(spec["indices"]),
            "--jobs", "1",
            "--out", str(out),
        ]  # fmt: skip
        try:
            p = run_deltaloop(cmd, stdin=subprocess.DEVNULL)
        except OSError as e:
            raise SweepError(f"cannot run {spec['deltaloop']!r} on {worker}: {e}") from None
        if p.returncode != 0:
            last = (p.stderr.strip().splitlines() or ["(no message)"])[-1]
            raise SweepError(f"deltaloop exited with {p.returncode}: {last}")
        files = {f: (out / f).read_text() for f in SHARD_FILES}
        got = json.loads(files["shard.json"])["plan_hash"]
        if got != spec["plan_hash"]:
            raise SweepError(
                f"the deltaloop on {worker} computes plan {got[:12]}, the driver's {spec['plan_hash'][:12]}:"
                " workers and driver must run the same deltaloop version"
            )
        tar = None
        if (out / "points").is_dir():
            buf = io.BytesIO()
            with tarfile.open(fileobj=buf, mode="w:gz") as t:
                t.add(out / "points", arcname="points")
            tar = buf.getvalue()
        return {
            "indices": spec["indices"],
            "files": files,
            "points_tar": tar,
            "worker": worker,
            "seconds": time.monotonic() - t0,
        }


@dataclass
class Result:
    """What :func:`run_sweep` did."""

    out: Path
    shards: Path
    points: int
    #: ``{point id: [error, ...]}`` of the points that failed the same way twice (or kept failing).
    failed: dict[str, list[str]] = field(default_factory=dict)
    #: Wall seconds from the first submit to the last result (merge excluded).
    run_seconds: float = 0.0
    #: Tasks submitted, retries included.
    tasks: int = 0


#: What a folder deltaloop claimed holds in its lock file (``MARK`` in
#: supervisor/report/src/lib.rs): the one sign ``--force`` trusts.
LOCK_FILE = ".deltaloop-lock"
MARK = b"deltaloop output folder: `--force` may empty it; locked while a command writes here\n"


def _is_marked(d: Path) -> bool:
    try:
        with open(d / LOCK_FILE, "rb") as f:
            return f.read(len(MARK)) == MARK
    except OSError:
        return False


class _Shard:
    """The driver's shard folder, grown as results arrive: one ``sweep.csv`` (rows appended),
    the sweep and base, the points' run folders, and ``shard.json`` listing what arrived."""

    def __init__(self, d: Path, sweep_file: str):
        self.dir, self.sweep_file = d, sweep_file
        self.csv = None
        self.manifest = None
        self.ids: list[str] = []

    def add(self, res: dict) -> None:
        files = res["files"]
        m = json.loads(files["shard.json"])
        if self.csv is None:
            self.dir.mkdir(parents=True, exist_ok=True)
            # Marked as deltaloop's, as a claimed folder is: a later --force may empty it.
            (self.dir / LOCK_FILE).write_bytes(MARK)
            for name in ("sweep.toml", "base.toml"):
                (self.dir / name).write_text(files[name])
            self.csv = open(self.dir / "sweep.csv", "w", newline="")
            self.csv.write(files["sweep.csv"])
            self.manifest = m
        else:
            # Same header (the same binary made it): append the rows only.
            self.csv.write(files["sweep.csv"].split("\n", 1)[1])
        self.csv.flush()
        self.ids += m["points"]
        if res["points_tar"]:
            with tarfile.open(fileobj=io.BytesIO(res["points_tar"]), mode="r:gz") as t:
                t.extractall(self.dir, filter="data")

    def close(self) -> None:
        """Writes ``shard.json`` (also after an interruption: it lists what arrived)."""
        if self.csv is None:
            return
        self.csv.close()
        m = dict(self.manifest)
        # The worker ran a shipped copy: name the file the user gave, as the report does.
        m["sweep_file"] = self.sweep_file
        m["points"] = sorted(self.ids)
        (self.dir / "shard.json").write_text(json.dumps(m, indent=2) + "\n")


def _say(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


def run_sweep(
    sweep_file: str | os.PathLike,
    client,
    out: str | os.PathLike,
    *,
    deltaloop: str | None = None,
    worker_deltaloop: str | None = None,
    batch: int = 1,
    force: bool = False,
    progress=_say,
    wait_workers_s: float = 60.0,
) -> Result:
    """Runs the sweep in ``sweep_file`` on the Dask cluster of ``client`` (a
    ``distributed.Client`` or a scheduler address) and merges it into ``out``.

    ``deltaloop`` is the driver's binary, ``worker_deltaloop`` the path on the workers (default:
    the same). ``batch`` points per task (realtime points always alone). Shard folders go to
    ``<out>.shards/`` and stay there (a later ``deltaloop sweep merge`` can use them). Raises
    :class:`SweepError` if points failed, after merging the rest (the report lists them)."""
    import cloudpickle
    from distributed import Client, as_completed

    # Tasks travel by value: workers need distributed and the deltaloop binary, not this package.
    cloudpickle.register_pickle_by_value(sys.modules[__name__])
    if batch < 1:
        raise SweepError(f"batch = {batch} is out of range: at least 1 point per task")
    exe = deltaloop or default_deltaloop()
    wexe = worker_deltaloop or exe
    sweep_file = str(sweep_file)
    out = Path(out)
    shards = Path(str(out) + ".shard")
    for d in (out, shards):
        if d.exists() and any(d.iterdir()):
            if not force:
                raise SweepError(f"{d} is not empty: choose another --out, or pass --force")
            # Like `deltaloop --force`: only a folder deltaloop claimed (its lock file marked) is
            # emptied; a stray lock file or a stranger's sweep.toml does not count.
            if not _is_marked(d):
                raise SweepError(f"{d} is not a deltaloop sweep folder: --force empties only those")
            shutil.rmtree(d)
    pl = plan(sweep_file, exe)
    points = pl["points"]
    if not isinstance(client, Client):
        client = Client(client)
    _check_workers(client, points, wait_workers_s)

    base_spec = {
        "deltaloop": wexe,
        "sweep_toml": pl["sweep_toml"],
        "base_toml": pl["base_toml"],
        "plan_hash": pl["plan_hash"],
    }
    errors: dict[tuple, list[str]] = {}
    failed: dict[str, list[str]] = {}
    futures = {}

    def submit(indices: list[int]):
        f = client.submit(
            run_points,
            {**base_spec, "indices": indices},
            resources=resources_for(points, indices),
            pure=False,
            key=f"deltaloop-{pl['plan_hash'][:8]}-{ranges_text(indices)}-{time.monotonic_ns()}",
        )
        futures[f.key] = indices
        return f

    t0 = time.monotonic()
    shard = _Shard(shards, sweep_file)
    ac = as_completed([submit(b) for b in batches(points, batch)])
    tasks = len(futures)
    done = 0
    try:
        for f in ac:
            indices = futures.pop(f.key)
            if f.status == "finished":
                res = f.result()
                shard.add(res)
                done += len(indices)
                first = points[indices[0]]
                what = first["id"] if len(indices) == 1 else f"{first['id']} +{len(indices) - 1}"
                progress(
                    f"[{done}/{len(points)}] {what} on {res['worker']} in {res['seconds']:.2f} s"
                )
            else:
                err = f.exception()
                msg = f"{type(err).__name__}: {err}"
                if len(indices) > 1:
                    # Which point failed is unknown: retry them one by one.
                    progress(f"batch {ranges_text(indices)} failed ({msg}); retrying point by point")
                    for i in indices:
                        errors[(i,)] = [msg]
                        ac.add(submit([i]))
                        tasks += 1
                    continue
                key = tuple(indices)
                seen = errors.setdefault(key, [])
                seen.append(msg)
                pid = points[indices[0]]["id"]
                if (len(seen) >= 2 and seen[-1] == seen[-2]) or len(seen) >= 3:
                    failed[pid] = seen
                    progress(f"point {pid} ({points[indices[0]]['label']}) failed twice: {msg}")
                else:
                    progress(f"point {pid} failed ({msg}); retrying")
                    ac.add(submit(indices))
                    tasks += 1
            f.release()
    finally:
        shard.close()
    run_seconds = time.monotonic() - t0
    if not shard.ids:
        raise SweepError(f"no point finished; failed: {failed}")
    cmd = [exe, "sweep", "merge", str(shards), "--out", str(out)]
    if failed:
        cmd.append("--allow-missing")
    m = run_deltaloop(cmd)
    result = Result(out, shards, len(points), failed, run_seconds, tasks)
    if failed:
        lines = "; ".join(f"{k}: {v[-1]}" for k, v in failed.items())
        raise SweepError(
            f"{len(failed)} of {len(points)} points failed twice ({lines}); the rest is merged in {out}"
        )
    if m.returncode != 0:
        raise SweepError(m.stderr.strip())
    progress(m.stdout.strip())
    return result


def _check_workers(client, points: list[dict], wait_s: float) -> None:
    """Waits for a worker, and refuses a cluster whose workers cannot run the points (a task
    whose resources no worker has would wait forever)."""
    try:
        client.wait_for_workers(1, timeout=wait_s)
    except TimeoutError:
        raise SweepError(f"no Dask worker joined within {wait_s:g} s") from None
    workers = client.scheduler_info(n_workers=-1)["workers"].values()
    cpu = max((w.get("resources", {}).get("CPU", 0) for w in workers), default=0)
    rt = max((w.get("resources", {}).get("RT", 0) for w in workers), default=0)
    hint = 'start workers with `dask worker ADDRESS --nthreads N --resources "CPU=N,RT=1"`'
    if cpu < 1:
        raise SweepError(f"no worker declares the resource CPU: {hint}")
    if any(p["mode"] == "realtime" for p in points) and (cpu < 2 or rt < 1):
        raise SweepError(
            f"the sweep has realtime points (2 CPUs and RT=1 each) and no worker offers them: {hint}"
        )


# --- Slurm -----------------------------------------------------------------------------------

#: Keys of the ``[slurm]`` section, with their meaning.
SLURM_KEYS = {
    "queue": "partition (#SBATCH -p)",
    "account": "account (#SBATCH -A)",
    "walltime": "job time limit, HH:MM:SS",
    "cores": "CPUs per job = worker threads = the worker's CPU resource",
    "memory": "memory per job, e.g. 8GB",
    "jobs": "Slurm jobs (one worker each) to start",
    "python": "the Python on the nodes (default: this one)",
    "job_extra_directives": "more #SBATCH lines, e.g. [\"--exclusive\"] for realtime points",
    "job_script_prologue": "shell lines before the worker starts, e.g. module loads",
    "local_directory": "worker scratch folder on the node",
}


def slurm_settings(path: str | os.PathLike | None = None, **overrides) -> dict:
    """The ``[slurm]`` section of a TOML file, with ``overrides`` (not None) on top."""
    cfg: dict = {}
    if path is not None:
        with open(path, "rb") as f:
            doc = tomllib.load(f)
        cfg = doc.get("slurm")
        if not isinstance(cfg, dict):
            raise SweepError(f"{path}: no [slurm] section (keys: {', '.join(SLURM_KEYS)})")
    cfg = {**cfg, **{k: v for k, v in overrides.items() if v is not None}}
    unknown = sorted(set(cfg) - set(SLURM_KEYS))
    if unknown:
        raise SweepError(
            f"slurm key `{unknown[0]}` is unknown: one of {', '.join(SLURM_KEYS)}"
        )
    cores = cfg.get("cores", 1)
    if not isinstance(cores, int) or isinstance(cores, bool) or cores < 1:
        raise SweepError(f"slurm key `cores` = {cores!r} is out of range: an integer >= 1")
    jobs = cfg.get("jobs", 1)
    if not isinstance(jobs, int) or isinstance(jobs, bool) or jobs < 1:
        raise SweepError(f"slurm key `jobs` = {jobs!r} is out of range: an integer >= 1")
    if "memory" not in cfg:
        raise SweepError("slurm key `memory` is missing: memory per job, e.g. \"8GB\"")
    return {**cfg, "cores": cores, "jobs": jobs}


def slurm_cluster(settings: dict, **cluster_kwargs):
    """A ``dask_jobqueue.SLURMCluster`` whose jobs each run one worker with ``cores`` threads and
    the resources ``CPU=cores, RT=1`` (not started: call ``.scale(jobs=...)``)."""
    from dask_jobqueue import SLURMCluster

    s = settings
    kw = {
        "cores": s["cores"],
        "processes": 1,
        "memory": s["memory"],
        "walltime": s.get("walltime"),
        "queue": s.get("queue"),
        "account": s.get("account"),
        "python": s.get("python"),
        "local_directory": s.get("local_directory"),
        "job_extra_directives": s.get("job_extra_directives", []),
        "job_script_prologue": s.get("job_script_prologue", []),
        "worker_extra_args": ["--resources", f"CPU={s['cores']},RT=1"],
    }
    kw = {k: v for k, v in kw.items() if v is not None}
    return SLURMCluster(**kw, **cluster_kwargs)


# --- command line ----------------------------------------------------------------------------


def _missing_extras(slurm: bool) -> str | None:
    """One line saying what to install when the ``dask`` extra is missing, else None."""
    import importlib

    for mod in ("distributed", "cloudpickle") + (("dask_jobqueue",) if slurm else ()):
        try:
            importlib.import_module(mod)
        except ImportError as e:
            return (
                f"python -m deltaloop.dask needs the `dask` extra, and {e.name or mod!r} is not"
                " installed: pip install './python[dask]' (from the repository), or"
                " pip install -r python/requirements.txt"
            )
    return None


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        prog="python -m deltaloop.dask",
        description="Run a deltaloop sweep on a Dask cluster (an existing scheduler, or Slurm "
        "jobs through dask-jobqueue) and merge it as `deltaloop sweep` would.",
    )
    ap.add_argument("sweep", help="sweep file (TOML)")
    where = ap.add_mutually_exclusive_group(required=True)
    where.add_argument("--scheduler", help="scheduler address, e.g. tcp://10.0.0.5:8786")
    where.add_argument("--scheduler-file", help="a scheduler file (dask scheduler --scheduler-file)")
    where.add_argument("--slurm", nargs="?", const="", metavar="CONFIG",
                       help="start workers as Slurm jobs; CONFIG: a TOML file with a [slurm] section")  # fmt: skip
    ap.add_argument("--out", required=True, help="the merged sweep folder (results: OUT.shard)")
    ap.add_argument("--force", action="store_true", help="empty and reuse a non-empty --out")
    ap.add_argument("--batch", type=int, default=1, help="points per task (default 1)")
    ap.add_argument("--deltaloop", help="the driver's deltaloop binary (default: $DELTALOOP or PATH)")
    ap.add_argument("--worker-deltaloop", help="the binary's path on the workers (default: --deltaloop)")
    ap.add_argument("--wait-workers", type=float, default=60.0, metavar="SECONDS",
                    help="how long to wait for the first worker (default 60)")  # fmt: skip
    for k in ("queue", "account", "walltime", "memory"):
        ap.add_argument(f"--{k}", help=f"Slurm: {SLURM_KEYS[k]}")
    ap.add_argument("--cores", type=int, help=f"Slurm: {SLURM_KEYS['cores']}")
    ap.add_argument("--jobs", type=int, help=f"Slurm: {SLURM_KEYS['jobs']}")
    ap.add_argument("--print-job-script", action="store_true",
                    help="Slurm: print the job script that would be submitted, and exit")  # fmt: skip
    a = ap.parse_args(argv)
    missing = _missing_extras(slurm=a.slurm is not None)
    if missing:
        print(f"deltaloop.dask: error: {missing}", file=sys.stderr)
        return 2

    from distributed import Client

    cluster = None
    try:
        if a.slurm is not None:
            s = slurm_settings(
                a.slurm or None, queue=a.queue, account=a.account, walltime=a.walltime,
                memory=a.memory, cores=a.cores, jobs=a.jobs,
            )  # fmt: skip
            cluster = slurm_cluster(s)
            if a.print_job_script:
                print(cluster.job_script())
                return 0
            cluster.scale(jobs=s["jobs"])
            client = Client(cluster)
        elif a.scheduler_file:
            client = Client(scheduler_file=a.scheduler_file)
        else:
            client = Client(a.scheduler)
        with client:
            r = run_sweep(
                a.sweep, client, a.out, deltaloop=a.deltaloop,
                worker_deltaloop=a.worker_deltaloop, batch=a.batch, force=a.force,
                wait_workers_s=a.wait_workers,
            )  # fmt: skip
        print(f"{r.points} points, {r.tasks} tasks, {r.run_seconds:.1f} s on the cluster; sweep folder: {r.out}")
        return 0
    except SweepError as e:
        print(f"deltaloop.dask: error: {e}", file=sys.stderr)
        return 1
    finally:
        if cluster is not None:
            cluster.close()


if __name__ == "__main__":
    # Run the importable module's main, so tasks name `deltaloop.dask.run_points`, not `__main__`.
    from deltaloop.dask import main as _main

    sys.exit(_main())
