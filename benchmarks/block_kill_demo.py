"""Kill a dask worker process in the middle of a block and show the block still completes (dask retries).

Usage: python benchmarks/block_kill_demo.py [--workdir DIR] [--copies N] [--kill-after K]

Builds the Middlebury-derived test block of tests/test_block.py (four crops of Cones, LiDAR from the ground truth,
plus the synthetic sample block when sample_data/block exists), repeated ``--copies`` times under different pair names
so the run lasts long enough. It runs the block once sequentially (``workers=0``, the reference), then on a
LocalCluster with 2 worker processes; after ``--kill-after`` matched tiles it finds the worker with the most tasks
assigned (pids from ``client.run(os.getpid)``) and kills it with SIGKILL. The nanny starts a new worker process, the
scheduler reruns the tasks that were running there and recomputes the results that died with it (``retries`` and
``distributed.scheduler.allowed-failures``). The script prints what happened and whether the merged DSM equals the
sequential one, as JSON.

The claim is held by tests/test_block_cluster.py (``test_killed_worker_process_block_completes_equal_to_sequential``
kills a worker of a process cluster mid-block through ``riverbed block --scheduler`` and asserts the kill landed
while work remained and the products equal the sequential run's; ``test_settled_pair_is_released_...`` a death after
a pair settled; ``test_killed_block_resumes_...`` a killed block resumed). This script stays as a demo at a size you
choose.
"""

import argparse
import json
import logging
import os
import shutil
import signal
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import rasterio
import yaml

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests"))


def build(base, copies):
    from test_block import write_cones_block

    write_cones_block(base)
    manifest = yaml.safe_load((base / "block.yaml").read_text())
    pairs = []
    for k in range(copies):
        for p in manifest["pairs"]:
            name = p.get("name") or Path(p["pair"]).parent.name
            pairs.append({**p, "name": f"{name}{k}"})
    manifest["pairs"] = pairs
    (base / "kill.yaml").write_text(yaml.safe_dump(manifest, sort_keys=False))
    return base / "kill.yaml"


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--workdir", type=Path, default=None)
    ap.add_argument("--copies", type=int, default=2)
    ap.add_argument("--kill-after", type=int, default=3, help="kill a worker after this many matched tiles")
    ap.add_argument("--retries", type=int, default=2)
    args = ap.parse_args()

    import dask
    from distributed import Client, LocalCluster

    from riverbed_cli.scale.block import plan_block, run_block

    logging.basicConfig(level=logging.WARNING, format="%(name)s: %(levelname)s: %(message)s")
    work = args.workdir or Path(tempfile.mkdtemp(prefix="riverbed-kill-"))
    shutil.rmtree(work, ignore_errors=True)
    work.mkdir(parents=True)
    manifest = build(work, args.copies)

    t0 = time.perf_counter()
    ref = run_block(plan_block(manifest, work / "seq"), workers=0)
    t_seq = time.perf_counter() - t0
    if any(p["status"] != "done" for p in ref.pairs):
        raise SystemExit(f"the sequential reference run failed: {ref.pairs}")

    with dask.config.set({"distributed.scheduler.allowed-failures": args.retries}):
        cluster = LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0",
                               silence_logs=logging.ERROR)
    client = Client(cluster)
    pids_before = client.run(os.getpid)
    events = {"tiles_done": 0, "killed": None}

    def progress(kind, name, n=1):
        if kind != "tile":
            return
        events["tiles_done"] += 1
        if events["killed"] is None and events["tiles_done"] >= args.kill_after:
            processing = client.processing()
            addr = max(processing, key=lambda a: len(processing[a]))
            pid = client.run(os.getpid)[addr]
            os.kill(pid, signal.SIGKILL)
            events["killed"] = {"worker": addr, "pid": pid, "tasks_assigned": list(processing[addr]),
                                "after_tiles": events["tiles_done"], "at_seconds": round(time.perf_counter() - t1, 2)}

    t1 = time.perf_counter()
    try:
        res = run_block(plan_block(manifest, work / "dask"), retries=args.retries, progress=progress, client=client)
        t_dask = time.perf_counter() - t1
        time.sleep(1.0)
        pids_after = client.run(os.getpid)
    finally:
        client.close()
        cluster.close()

    with rasterio.open(work / "seq" / "dsm.tif") as a, rasterio.open(work / "dask" / "dsm.tif") as b:
        same = a.transform == b.transform and np.array_equal(a.read(1), b.read(1), equal_nan=True)
    out = {
        "pairs": len(res.pairs),
        "statuses": sorted({p["status"] for p in res.pairs}),
        "failed": [p for p in res.pairs if p["status"] == "failed"],
        "merged": res.merged.get("status"),
        "merged_dsm_equals_sequential": bool(same),
        "killed": events["killed"],
        "worker_pids_before": sorted(pids_before.values()),
        "worker_pids_after": sorted(pids_after.values()),
        "seconds_sequential": round(t_seq, 2),
        "seconds_dask_with_kill": round(t_dask, 2),
        "workdir": str(work),
    }
    print(json.dumps(out, indent=2))
    return 0 if out["statuses"] == ["done"] and same and events["killed"] else 1


if __name__ == "__main__":
    sys.exit(main())
