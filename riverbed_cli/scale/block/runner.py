"""Running a planned block: the pairs' stages as dask.distributed tasks (or in order, in this process), then the
merged DSM."""

import json
import logging
import os
import shutil
import time
import uuid
from dataclasses import dataclass
from pathlib import Path

import numba

from ...errors import RiverbedError
from ...io.atomic import unlock_folder
from .merge import merge_dsm, merge_heights, merge_settings
from .plan import DONE, MARKER, MERGED, WORK, clean_temps, sha256_file, write_json
from .stages import PairFailure, finish_stage, n_tasks, project_stage, tile_stage

log = logging.getLogger(__name__)


def _numba_threads(n):
    """Inside a task: set this thread's Numba threads (``n``; None: the worker host's CPUs / the worker's threads)."""
    if n == 0:
        return
    if n is None:
        try:
            from distributed import get_worker  # lazy: dask is optional (the dask extra)

            w = get_worker()
            n = max(1, (os.cpu_count() or 1) // max(1, getattr(w.state, "nthreads", None) or w.nthreads))
        except (ImportError, ValueError):
            return
    numba.set_num_threads(max(1, min(int(n), numba.config.NUMBA_NUM_THREADS)))


def _guard(stage, fn, *args):
    try:
        return fn(*args)
    except RiverbedError as e:  # a stage may name a finer one (the project task's "rectify")
        return PairFailure(getattr(e, "stage", None) or stage, str(e))


def task_project(job, threads):
    _numba_threads(threads)
    return _guard("project", project_stage, job)


def task_tile(job, pair_plan, index, threads):
    if isinstance(pair_plan, PairFailure):
        return pair_plan
    _numba_threads(threads)
    return _guard("match", tile_stage, job, pair_plan, index)


def task_finish(job, pair_plan, tiles, threads):
    for r in (pair_plan, *tiles):
        if isinstance(r, PairFailure):
            return r
    _numba_threads(threads)
    result = _guard("dsm", finish_stage, job, pair_plan, tiles)
    if isinstance(result, dict):  # the Numba threads this task ran with (the summary's, not done.json's)
        result = {**result, "numba_threads": numba.get_num_threads()}
    return result


def task_merge(laz_paths, output, resolution, agg, crs, heights=None, changes=()):
    clean_temps(Path(output).parent, (Path(output).name, "change.tif"))  # a merge killed mid-write and retried
    return _guard("merge", merge_dsm, laz_paths, output, resolution, agg, crs, 1_000_000, heights, changes)


def _describe(exc):
    text = str(exc).splitlines()[0] if str(exc) else ""
    return f"{type(exc).__name__}: {text}" if not isinstance(exc, RiverbedError) else text


@dataclass
class BlockResult:
    outdir: Path
    pairs: list  # one dict per pair, manifest order
    merged: dict
    mode: str
    seconds: float
    cluster_seconds: float = None  # starting (or connecting to) the cluster
    plan_seconds: float = 0.0
    cluster: dict = None  # the dask cluster the pairs ran on (None: sequential, or nothing to run)
    cleaned: list = None  # leftovers of an interrupted run removed by the plan (paths relative to outdir)

    @property
    def failed(self):
        return [p for p in self.pairs if p["status"] == "failed"] + (
            [self.merged] if self.merged.get("status") == "failed" else [])

    def summary(self):
        return {"outdir": str(self.outdir), "mode": self.mode, "seconds": round(self.seconds, 3),
                "plan_seconds": round(self.plan_seconds, 3),
                "cluster_seconds": None if self.cluster_seconds is None else round(self.cluster_seconds, 3),
                "cluster": self.cluster, "cleaned": list(self.cleaned or []), "pairs": self.pairs,
                "merged": self.merged}


def _pair_entry(job, status, seconds=None, summary=None, error=None, stage=None):
    """One pair's line of the summary: ``seconds`` is the wall time of the pair in this run (on dask from its first
    submission to its end, queueing included), ``stage_seconds`` the compute time of its stages (pairs run now)."""
    summary = summary or {}
    return {"name": job.name, "status": status, "seconds": None if seconds is None else round(seconds, 3),
            "points": summary.get("points"), "tiles": summary.get("tiles"), "error": error, "stage": stage,
            "stage_seconds": summary.get("seconds") if status == "done" else None,
            "numba_threads": summary.get("numba_threads") if status == "done" else None}


def _default_workers(threads_per_worker):
    return max(1, (os.cpu_count() or 1) // max(1, threads_per_worker))


def run_block(plan, workers=None, threads_per_worker=1, scheduler=None, retries=2, progress=None, client=None):
    """Run the pairs of a plan (sequentially with ``workers=0``, else on dask.distributed), then merge the DSM.

    Parameters
    ----------
    plan : BlockPlan
    workers : int, optional
        Worker processes of the local cluster (default: CPUs / ``threads_per_worker``); 0 runs the same stage
        functions in this process, in manifest order, without dask.
    threads_per_worker : int
        Dask threads per worker process; inside each task Numba gets ``CPUs // (workers * threads)`` threads.
    scheduler : str, optional
        Address of a running dask scheduler (its workers must see the same paths and have riverbed installed).
    retries : int
        How often a task is redone after an unexpected exception, and (local cluster) how many worker deaths a task
        survives (``distributed.scheduler.allowed-failures``). Bad input is never retried.
    client : distributed.Client, optional
        Run on this client's cluster (left open); ``workers`` and ``scheduler`` are then ignored.
    progress : callable, optional
        ``progress(kind, name, n=1)``: ``"plan"`` (a pair's ``n`` matching tasks are known), ``"tile"`` (one matched),
        ``"pair"`` (a pair settled).

    Returns
    -------
    BlockResult
    """
    t0 = time.perf_counter()
    entries, startup, info = {}, None, None
    for job in plan.jobs:
        if job.status == "failed":
            entries[job.name] = _pair_entry(job, "failed", 0.0, error=job.error, stage="plan")
        elif job.status == "skip":
            entries[job.name] = _pair_entry(job, "skipped", 0.0, summary=job.record.get("stats"))
    to_run = plan.to_run
    if scheduler is not None and workers is not None:
        raise RiverbedError("give --workers (a local cluster) or --scheduler (a running one), not both")
    sequential = workers == 0 and client is None
    mode = "client" if client is not None else "sequential" if sequential else ("scheduler" if scheduler else "local")
    own = client is None
    cluster = None
    try:
        if to_run and sequential:
            entries.update(_run_sequential(to_run, progress))
        elif to_run:
            t1 = time.perf_counter()
            threads = None
            if own:
                client, cluster, threads = _connect(workers, threads_per_worker, scheduler, retries)
            startup = time.perf_counter() - t1
            info = _cluster_info(client, threads)
            log.info("dask cluster at %s: %d workers, threads per worker %s, Numba threads per task %s",
                     info["scheduler"], info["workers"], info["threads_per_worker"],
                     info["numba_threads"] if threads is not None else "CPUs of its host / its threads")
            entries.update(_run_dask(client, to_run, retries, threads, progress))
        for job in to_run:  # a failed pair's image copies are not kept
            if entries[job.name]["status"] == "failed":
                shutil.rmtree(Path(job.folder) / WORK, ignore_errors=True)
        merged = _merge(plan, entries, client, retries)
    finally:
        if own and client is not None:
            client.close()
        if cluster is not None:
            cluster.close()
        unlock_folder(plan.outdir)  # locked by plan_block
    pairs = [entries[j.name] for j in plan.jobs]
    cleaned = sorted(Path(p).relative_to(plan.outdir).as_posix() for p in plan.cleaned)
    return BlockResult(plan.outdir, pairs, merged, mode, time.perf_counter() - t0, startup, plan.seconds, info,
                       cleaned)


def _cluster_info(client, threads):
    """The cluster the block runs on, as its scheduler reports it: address, workers, each worker's threads (sorted)
    and the Numba threads a task sets (``threads``; None on an existing cluster: each host's CPUs / its threads)."""
    info = client.scheduler_info(n_workers=-1)
    workers = info.get("workers", {})
    return {"scheduler": info.get("address"), "workers": len(workers),
            "threads_per_worker": sorted(int(w["nthreads"]) for w in workers.values()), "numba_threads": threads}


def _quiet_dask_logs():
    """dask's own INFO chatter (scheduler start, workers joining) stays out of riverbed's log unless it is at DEBUG
    (``-vv``); its warnings (a worker lost, a task retried) and errors still show."""
    if logging.getLogger().getEffectiveLevel() <= logging.DEBUG:
        return
    for name in list(logging.root.manager.loggerDict):
        if name.split(".")[0] in ("distributed", "dask", "tornado", "bokeh"):
            logger = logging.getLogger(name)
            if logger.level < logging.WARNING:
                logger.setLevel(logging.WARNING)


def _connect(workers, threads_per_worker, scheduler, retries):
    try:  # lazy: dask is optional (the dask extra); without it only --workers 0 runs
        import dask
        from distributed import Client, LocalCluster
    except ImportError:
        raise RiverbedError("dask.distributed is not installed: pip install 'riverbed[dask]', or run the block "
                            "with --workers 0 (sequential)") from None
    _quiet_dask_logs()
    if scheduler:
        try:
            client = Client(scheduler, timeout="20s")
        except (OSError, TimeoutError) as e:
            raise RiverbedError(f"cannot reach the dask scheduler at {scheduler} ({e})") from None
        return client, None, None
    n = workers if workers is not None else _default_workers(threads_per_worker)
    threads = max(1, (os.cpu_count() or 1) // (n * threads_per_worker))
    with dask.config.set({"distributed.scheduler.allowed-failures": int(retries)}):
        cluster = LocalCluster(n_workers=n, threads_per_worker=threads_per_worker, processes=True,
                               dashboard_address=":0", silence_logs=logging.ERROR)
    try:
        client = Client(cluster)
        try:
            client.wait_for_workers(n, timeout="60s")  # every worker counted in the summary's cluster
        except TimeoutError:
            client.close()
            raise RiverbedError(f"the local dask cluster's {n} workers did not all start within 60 s") from None
    except BaseException:
        cluster.close()
        raise
    return client, cluster, threads


def _run_dask(client, jobs, retries, threads, progress):
    """Submit each pair's project task; when it is done, its tile tasks (they depend on the project future) and the
    finish task (depends on all of them). Returns the pairs' entries."""
    from distributed import as_completed  # lazy: dask is optional (the dask extra)

    run = uuid.uuid4().hex[:8]
    opts = {"retries": retries, "pure": False}
    kinds, started, entries = {}, {}, {}
    ac = as_completed()
    for job in jobs:
        fp = client.submit(task_project, job, threads, key=f"project-{job.name}-{run}", **opts)
        kinds[fp.key] = ("project", job)
        started[job.name] = time.perf_counter()
        ac.add(fp)
    for fut in ac:
        kind, job = kinds[fut.key]
        settled = _settle(client, fut, kind, job, threads, run, opts, kinds, ac, entries, started, progress)
        # Release every future once handled: a result nobody waits for any more must not be recomputed when the
        # worker holding it dies (a finished pair's project would delete its done.json and redo the pair behind
        # the block's back); the scheduler still keeps what waiting tasks depend on.
        fut.release()
        if settled and progress:
            progress("pair", job.name)
    return entries


def _settle(client, fut, kind, job, threads, run, opts, kinds, ac, entries, started, progress):
    """Handle one finished future of ``_run_dask``: a project submits its pair's tiles and finish; a failure or a
    finish settles the pair (returns True)."""
    if kind == "tile":
        if progress:
            progress("tile", job.name)
        return False
    seconds = time.perf_counter() - started[job.name]
    if fut.status != "finished":
        exc = fut.exception() if fut.status == "error" else None
        entries[job.name] = _pair_entry(job, "failed", seconds, error=_describe(exc) if exc is not None
                                        else f"task {fut.status}", stage=kind if kind == "project" else None)
    elif kind == "project" and not isinstance(pair_plan := fut.result(), PairFailure):
        n = n_tasks(pair_plan)
        if progress:
            progress("plan", job.name, n)
        fts = [client.submit(task_tile, job, fut, i, threads, key=f"tile-{job.name}-{i}-{run}", **opts)
               for i in range(n)]
        ff = client.submit(task_finish, job, fut, fts, threads, key=f"finish-{job.name}-{run}", **opts)
        kinds.update({f.key: ("tile", job) for f in fts})
        kinds[ff.key] = ("finish", job)
        ac.update([*fts, ff])
        return False
    else:
        entries[job.name] = _entry_from(job, fut.result(), seconds)
    return True


def _entry_from(job, result, seconds):
    if isinstance(result, PairFailure):
        return _pair_entry(job, "failed", seconds, error=result.message, stage=result.stage)
    return _pair_entry(job, "done", seconds, result)


def _run_sequential(jobs, progress):
    """The same task functions as on dask, in this process, pair after pair (Numba threads left as they are)."""
    entries = {}
    for job in jobs:
        t1 = time.perf_counter()
        try:
            result = pair_plan = task_project(job, 0)
            if not isinstance(pair_plan, PairFailure):
                if progress:
                    progress("plan", job.name, n_tasks(pair_plan))
                tiles = []
                for i in range(n_tasks(pair_plan)):
                    tiles.append(task_tile(job, pair_plan, i, 0))
                    if progress:
                        progress("tile", job.name)
                result = task_finish(job, pair_plan, tiles, 0)
        except Exception as e:  # one pair's crash must not stop the block
            log.debug("pair %s failed", job.name, exc_info=True)
            result = PairFailure(None, _describe(e))
        entries[job.name] = _entry_from(job, result, time.perf_counter() - t1)
        if progress:
            progress("pair", job.name)
    return entries


def _merge(plan, entries, client, retries):
    """Merge the finished pairs' points into ``OUTDIR/dsm.tif`` unless the last merge used exactly these pairs."""
    t0 = time.perf_counter()
    good = [j for j in plan.jobs if entries[j.name]["status"] in ("done", "skipped")]
    output = plan.outdir / MERGED
    if not good:
        return {"status": "failed", "error": "no pair finished: no merged DSM", "output": None}
    records, hashes = {}, {}
    try:
        for j in good:
            path = Path(j.folder) / DONE
            records[j.name] = json.loads(path.read_text(encoding="utf-8"))
            hashes[j.name] = sha256_file(path)
        resolution, crs = merge_settings(plan, records)
        heights = merge_heights(records)
    except (OSError, ValueError, KeyError) as e:
        return {"status": "failed", "error": f"cannot read a finished pair's record ({e})", "output": None}
    except RiverbedError as e:
        return {"status": "failed", "error": str(e), "output": None}
    agg = plan.manifest.defaults["agg"]
    key = {"pairs": hashes, "resolution": resolution, "agg": agg, "crs": crs}
    marker = plan.outdir / MARKER
    try:
        record = json.loads(marker.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        record = {}
    last = record.get("merged") or {}
    if (last.get("key") == key and output.is_file() and output.stat().st_size == last.get("size")
            and sha256_file(output) == last.get("sha256")):
        return {"status": "skipped", "output": str(output), **last.get("stats", {}),
                "seconds": round(time.perf_counter() - t0, 3)}
    paths = [str(Path(j.folder) / "points.laz") for j in good]
    changes = [str(Path(j.folder) / "change.tif") for j in good if (Path(j.folder) / "change.tif").is_file()]
    (plan.outdir / "change.tif").unlink(missing_ok=True)  # a previous merge's: this one writes its own, if any
    if client is not None:
        fut = client.submit(task_merge, paths, str(output), resolution, agg, crs, heights, changes,
                            key=f"merge-{uuid.uuid4().hex[:8]}", retries=retries, pure=False)
        try:
            stats = fut.result()
        except Exception as e:  # noqa: BLE001 - reported like a failed pair
            stats = PairFailure("merge", _describe(e))
    else:
        stats = _guard("merge", merge_dsm, paths, output, resolution, agg, crs, 1_000_000, heights, changes)
    if isinstance(stats, PairFailure):
        return {"status": "failed", "error": stats.message, "output": None}
    record["merged"] = {"key": key, "size": output.stat().st_size, "sha256": sha256_file(output), "stats": stats}
    write_json(marker, record)
    return {"status": "done", "output": str(output), "pairs": len(good), "crs": crs, **stats,
            "seconds": round(time.perf_counter() - t0, 3)}
