"""riverbed block on process-based dask clusters and across interruptions (issue 13): a worker process killed
mid-block, ``--scheduler`` with a process cluster, a killed block resumed, changed inputs re-running their pair only,
``--workers`` / ``--threads-per-worker`` reaching the cluster.

Every run is compared with one sequential run (``--workers 0``) of the same manifest: the merged DSM bitwise (NaN where
NaN) and each pair's four outputs byte for byte (their sha256 in ``done.json``). The block is the four Cones crops of
``tests/test_block.py`` (200 x 240 px, three in 4 tiles, one untiled): about a second of matching per pair.
"""

import json
import os
import re
import shutil
import signal
import subprocess
import time

import numba
import numpy as np
import pytest
import rasterio
import yaml
from click.testing import CliRunner
from distributed import Client, LocalCluster

from riverbed_cli.cli.main import cli
from riverbed_cli.geometry.pairfile import load_pairfile
from riverbed_cli.io.disparity import read_disparity
from riverbed_cli.io.images import read_image
from riverbed_cli.io.lidar import read_lidar
from riverbed_cli.io.pointcloud import write_points
from riverbed_cli.products.visualize import write_png
from riverbed_cli.scale.block import plan_block, run_block
from riverbed_cli.scale.tiles import match_tiled
from test_block import CRS, write_cones_block
from conftest import RIVERBED

OUTPUTS = ["disparity.tif", "done.json", "dsm.tif", "points.laz", "sparse.tif"]
PAIRS = ["a", "b_pair", "c", "d_pair"]
WAIT = 180  # s: the longest any wait below may take before the test fails (a block here takes a few seconds)
#: s: the wait for a killed block's progress, whose dask workers start, load their kernels and work on a machine the
#: rest of the suite may load too (a block alone takes about 10 s; twice, a full suite beside other work took more
#: than 180 s). A hang fails after it with what the block printed and had written.
PROGRESS_WAIT = 600
TEMP = re.compile(r"^\..+\.[0-9a-f]{8}\.tmp(\.\w+)?$")  # io.atomic's temporary names, written out independently


# -- the block and its sequential reference ---------------------------------------------------------------------------

@pytest.fixture(scope="module")
def block(tmp_path_factory):
    """Inputs (``base``), the manifest ``cluster.yaml`` and its sequential run in ``base/seq``.

    Pair ``a`` has a cloud of its own (``own/a.laz``: the west and east tiles in one file), so changing it concerns
    that pair only; ``b_pair`` is the only pair reading ``b/left.png``.
    """
    base = write_cones_block(tmp_path_factory.mktemp("cluster"))
    (base / "own").mkdir()
    xyz = np.concatenate([read_lidar(base / "lidar" / f"{side}.laz")["xyz"] for side in ("west", "east")])
    write_points(base / "own" / "a.laz", xyz, None, CRS)
    pairs = [{"pair": "a/pair.yaml", "cloud": "own/a.laz", "name": "a"},
             {"pair": "b/pair.yaml", "cloud": ["lidar/west.laz", "lidar/east.laz"]},
             {"pair": "c/pair.yaml", "cloud": "lidar/*st.laz", "name": "c"},
             {"pair": "d/pair.yaml", "cloud": "lidar/*st.laz", "tile": 256}]  # not tiled: one match_pair task
    defaults = {"resolution": 1.0, "agg": "max", "tile": 128, "overlap": 32}
    (base / "cluster.yaml").write_text(yaml.safe_dump({"defaults": defaults, "pairs": pairs}, sort_keys=False))
    info = cli_json(["block", str(base / "cluster.yaml"), "-o", str(base / "seq"), "--workers", "0", "--json"])
    assert [p["name"] for p in info["pairs"]] == PAIRS and statuses(info) == dict.fromkeys(PAIRS, "done")
    assert [p["tiles"] for p in info["pairs"]] == [4, 4, 4, 0] and info["cluster"] is None
    return base


@pytest.fixture(scope="module")
def process_cluster():
    """A running process-based cluster, as a user would start one: 2 worker processes (nannies restart a killed
    one), 1 thread each; closed however the tests end."""
    cluster = LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0",
                           silence_logs=40)
    try:
        client = Client(cluster)
        try:
            client.wait_for_workers(2, timeout=WAIT)
            yield cluster, client
        finally:
            client.close()
    finally:
        cluster.close()


def cli_json(args):
    res = CliRunner().invoke(cli, args, catch_exceptions=False)
    assert res.exit_code == 0, res.stderr
    return json.loads(res.stdout)


def statuses(info):
    return {p["name"]: p["status"] for p in info["pairs"]}


def riverbed(*args):
    """The command line of ``riverbed ARGS`` in a fresh process (this interpreter, this checkout)."""
    return [*RIVERBED, *map(str, args)]


def read_dsm(path):
    with rasterio.open(path) as ds:
        return ds.read(1), ds.transform, ds.crs


def output_hashes(out, name):
    return json.loads((out / "pairs" / name / "done.json").read_text())["outputs"]


def assert_equals_reference(base, out, names=PAIRS):
    """``out`` holds exactly the reference's products: the merged DSM bitwise, each pair's outputs byte for byte,
    and nothing else (no temporary file, no ``.work``)."""
    a, ta, ca = read_dsm(base / "seq" / "dsm.tif")
    b, tb, cb = read_dsm(out / "dsm.tif")
    assert (ta, ca) == (tb, cb) and a.shape == b.shape
    np.testing.assert_array_equal(a, b)  # NaN where NaN, every height bit for bit
    for name in names:
        assert output_hashes(out, name) == output_hashes(base / "seq", name), name
        assert sorted(p.name for p in (out / "pairs" / name).iterdir()) == OUTPUTS, name
    assert sorted(p.name for p in out.iterdir()) == ["block.json", "dsm.tif", "pairs"]


def finished(out):
    """Pairs with a ``done.json`` (written last, by an atomic rename)."""
    return sorted(p.parent.name for p in (out / "pairs").glob("*/done.json")) if (out / "pairs").is_dir() else []


def wait_until(condition, proc, what, deadline, report=lambda: ""):
    """Poll ``condition()`` every 10 ms while ``proc`` runs; fail if ``proc`` ends first or the deadline passes,
    with ``report()`` (what the block printed and wrote) in the message."""
    start = time.monotonic()
    while True:
        value = condition()
        if value:
            return value
        if proc.poll() is not None:
            pytest.fail(f"the block ended (exit code {proc.returncode}) before {what}{report()}")
        if time.monotonic() > deadline:
            pytest.fail(f"no {what} within {time.monotonic() - start:.0f} s{report()}")
        time.sleep(0.01)


def stop(proc):
    """End a block process this test started (and its process group) if it still runs."""
    if proc.poll() is None:
        os.killpg(proc.pid, signal.SIGKILL)
    proc.wait(timeout=WAIT)


# -- an existing process cluster (--scheduler) ----------------------------------------------------------------------

def test_scheduler_with_a_process_cluster_equals_sequential(block, process_cluster, tmp_path):
    base = block
    cluster, client = process_cluster
    res = subprocess.run(riverbed("block", base / "cluster.yaml", "-o", tmp_path / "out", "--scheduler",
                                  cluster.scheduler_address, "--json"), capture_output=True, text=True,
                         timeout=WAIT)
    assert res.returncode == 0, res.stderr
    info = json.loads(res.stdout)
    assert info["mode"] == "scheduler" and statuses(info) == dict.fromkeys(PAIRS, "done")
    assert info["merged"]["status"] == "done" and info["merged"]["pairs"] == 4 and info["cleaned"] == []
    # the cluster as its scheduler reports it; on an existing cluster a task takes its host's CPUs / its threads
    assert info["cluster"] == {"scheduler": cluster.scheduler_address, "workers": 2, "threads_per_worker": [1, 1],
                               "numba_threads": None}
    per_task = min(os.cpu_count(), numba.config.NUMBA_NUM_THREADS)
    assert [p["numba_threads"] for p in info["pairs"]] == [per_task] * 4
    assert_equals_reference(base, tmp_path / "out")


def test_killed_worker_process_block_completes_equal_to_sequential(block, process_cluster, tmp_path):
    """SIGKILL one worker process of the cluster once the first pair has finished, while that worker runs a task of
    the block: the scheduler reruns its tasks elsewhere and recomputes the results that died with it; the block
    completes with every pair done and the sequential run's products."""
    base = block
    cluster, client = process_cluster
    out = tmp_path / "out"
    client.wait_for_workers(2, timeout=WAIT)
    pids_before = client.run(os.getpid)
    with open(tmp_path / "stdout", "w") as so, open(tmp_path / "stderr", "w") as se:
        proc = subprocess.Popen(riverbed("block", base / "cluster.yaml", "-o", out, "--scheduler",
                                         cluster.scheduler_address, "--json"), stdout=so, stderr=se,
                                start_new_session=True)
    try:
        deadline = time.monotonic() + PROGRESS_WAIT

        def busy_worker():  # once a pair has finished: the worker with the most tasks of the block running
            if not finished(out):
                return None
            busy = {a: len(keys) for a, keys in client.processing().items() if keys and a in pids_before}
            return max(busy, key=busy.get) if busy else None

        victim = wait_until(busy_worker, proc, "a first pair finished while a worker was busy", deadline,
                            lambda: f"\nstderr (end): {(tmp_path / 'stderr').read_text()[-2000:]}")
        pid = pids_before[victim]
        os.kill(pid, signal.SIGKILL)
        done_at_kill = finished(out)
        proc.wait(timeout=WAIT)
    finally:
        stop(proc)
    stderr = (tmp_path / "stderr").read_text()
    assert proc.returncode == 0, stderr
    assert 1 <= len(done_at_kill) < len(PAIRS), done_at_kill  # the kill landed while pairs were left to do
    # the scheduler saw a worker die (not close): it held tasks of this block, now rerun or recomputed elsewhere
    events = [e for _, e in client.get_events("all") if e.get("action") == "remove-worker"
              and e.get("worker") == victim]
    assert len(events) == 1 and events[0]["expected"] is False
    lost = set(events[0]["processing-tasks"]) | set(events[0]["lost-computed-tasks"])
    assert lost and all(re.match(r"(project|tile|finish|merge)-", k) for k in lost), lost
    client.wait_for_workers(2, timeout=WAIT)  # the nanny has started a new worker process
    assert pid in pids_before.values() and pid not in client.run(os.getpid).values()
    info = json.loads((tmp_path / "stdout").read_text())
    assert info["mode"] == "scheduler" and statuses(info) == dict.fromkeys(PAIRS, "done")
    assert info["merged"]["status"] == "done" and info["merged"]["pairs"] == 4
    assert_equals_reference(base, out)
    print(f"\nkilled worker pid {pid} with {done_at_kill} finished; lost {sorted(lost)}")


def test_settled_pair_is_released_and_a_later_worker_death_does_not_redo_it(block, process_cluster, tmp_path):
    """Once a pair has settled no client wants its tasks' results: the scheduler forgets them, so a worker dying
    later, with them in its memory, cannot make the scheduler recompute the pair behind the block's back (its
    project would delete the pair's done.json and rewrite its outputs after the block reported it done)."""
    base = block
    cluster, client = process_cluster
    client.wait_for_workers(2, timeout=WAIT)
    pids = client.run(os.getpid)
    out = tmp_path / "out"
    seen = {}

    def tasks_of(name):
        pattern = rf"(project|tile|finish)-{re.escape(name)}-"
        return client.run_on_scheduler(lambda dask_scheduler: sorted(
            k for k in dask_scheduler.tasks if re.match(pattern, str(k))))

    def progress(kind, name, n=1):
        if kind != "pair" or seen:
            return
        deadline = time.monotonic() + 10  # releases reach the scheduler in milliseconds
        while (left := tasks_of(name)) and time.monotonic() < deadline:
            time.sleep(0.01)
        busy = [a for a, keys in client.processing().items() if keys and a in pids]
        seen.update(name=name, left=left, mtimes={f: (out / "pairs" / name / f).stat().st_mtime_ns for f in OUTPUTS},
                    pid=pids[(busy or sorted(pids))[0]])
        os.kill(seen["pid"], signal.SIGKILL)

    res = run_block(plan_block(base / "cluster.yaml", out), client=client, progress=progress)
    assert seen and seen["left"] == [], seen  # every task of the settled pair forgotten
    assert statuses(res.summary()) == dict.fromkeys(PAIRS, "done") and res.merged["status"] == "done"
    name = seen["name"]
    assert {f: (out / "pairs" / name / f).stat().st_mtime_ns for f in OUTPUTS} == seen["mtimes"]  # not redone
    client.wait_for_workers(2, timeout=WAIT)
    assert seen["pid"] not in client.run(os.getpid).values()
    assert_equals_reference(base, out)


# -- an interrupted block resumed -----------------------------------------------------------------------------------

def test_killed_block_resumes_cleans_leftovers_and_skips_finished_pairs(block, tmp_path):
    """Kill ``riverbed block`` (its process group: the block and its local cluster's workers) once a pair has
    finished and another is half done; plant the temporary files a kill mid-write leaves (io.atomic's names) where
    the kill could not be timed to leave them; the re-run removes them all, skips exactly the finished pairs and
    runs the rest, to the sequential run's products."""
    base = block
    out = tmp_path / "out"
    with open(tmp_path / "stdout", "w") as so, open(tmp_path / "stderr", "w") as se:
        proc = subprocess.Popen(riverbed("block", base / "cluster.yaml", "-o", out, "--workers", "2", "--json"),
                                stdout=so, stderr=se, start_new_session=True)
    try:
        deadline = time.monotonic() + PROGRESS_WAIT

        def half_done():  # a pair finished and another projected (sparse.tif) but not finished
            done = finished(out)
            started = [p.parent.name for p in (out / "pairs").glob("*/sparse.tif")] if done else []
            return done and set(started) - set(done)

        def report():
            files = sorted(p.relative_to(out).as_posix() for p in out.rglob("*") if p.is_file()) if out.exists() else []
            err = (tmp_path / "stderr").read_text()[-2000:]
            return f"\nfiles: {files}\nstderr (end): {err}"

        wait_until(half_done, proc, "a pair finished and another half done", deadline, report)
        os.killpg(proc.pid, signal.SIGKILL)  # as a batch system ends a job: every process of the group
        proc.wait(timeout=WAIT)
    finally:
        stop(proc)
    assert proc.returncode == -signal.SIGKILL
    deadline = time.monotonic() + WAIT
    while True:  # the workers (same process group) are gone too
        try:
            os.killpg(proc.pid, 0)
        except ProcessLookupError:
            break
        assert time.monotonic() < deadline, "the killed block's workers are still running"
        time.sleep(0.05)
    done = finished(out)
    assert 1 <= len(done) < len(PAIRS), done
    half = sorted({p.parent.name for p in (out / "pairs").glob("*/sparse.tif")} - set(done))
    assert half and not (out / "dsm.tif").exists()

    # What a kill at other moments leaves: a temporary of each output being written, and a finished pair's image
    # copies (killed between its done.json and removing its .work).
    planted = [f"pairs/{half[0]}/.disparity.0123abcd.tmp.tif", f"pairs/{half[0]}/.done.89abcdef.tmp.json",
               f"pairs/{half[0]}/.work/.left.0badc0de.tmp.npy", f"pairs/{done[0]}/.work/left.npy",
               ".dsm.fedcba98.tmp.tif", ".block.00ff00ff.tmp.json"]
    for name in planted:
        (out / name).parent.mkdir(exist_ok=True)
        (out / name).write_bytes(b"half written")
    keep = out / "pairs" / half[0] / "notes.dsm.12345678.tmp.txt"  # not a temporary name: left alone
    keep.write_text("mine")
    # everything the re-run must remove: every temporary file in the block's folders (planted or left by the kill)
    # and the .work of the finished pairs
    leftovers = sorted({p.relative_to(out).as_posix() for p in out.rglob("*")
                        if p.is_file() and (TEMP.match(p.name) or (p.parent.name == ".work"
                                                                   and p.parent.parent.name in done))})
    assert set(planted) <= set(leftovers)

    info = cli_json(["block", str(base / "cluster.yaml"), "-o", str(out), "--workers", "0", "--json"])
    assert statuses(info) == {n: "skipped" if n in done else "done" for n in PAIRS}
    assert info["cleaned"] == leftovers
    assert not any(TEMP.match(p.name) for p in out.rglob("*")) and keep.read_text() == "mine"
    keep.unlink()
    assert info["merged"]["status"] == "done" and info["merged"]["pairs"] == 4
    assert_equals_reference(base, out)


# -- changed inputs re-run their pair only --------------------------------------------------------------------------

def copy_block(base, tmp_path):
    """The inputs and the finished sequential block, copied with their mtimes (so they hash the same), the copied
    block belonging to the copied manifest."""
    copy = tmp_path / "copy"
    shutil.copytree(base, copy, ignore=shutil.ignore_patterns("out*"))
    marker = copy / "seq" / "block.json"
    record = json.loads(marker.read_text())
    record["manifest"] = str(copy / "cluster.yaml")
    marker.write_text(json.dumps(record))
    return copy


def test_changed_image_reruns_its_pair_only(block, tmp_path):
    copy = copy_block(block, tmp_path)
    out = copy / "seq"
    pair = load_pairfile(copy / "b" / "pair.yaml")
    left = read_image(pair.left)
    left[50:150, 60:180] = 255 - left[50:150, 60:180]  # a patch of the left image inverted
    write_png(pair.left, left, overwrite=True)
    before = read_disparity(out / "pairs" / "b_pair" / "disparity.tif")
    sparse_before = read_disparity(out / "pairs" / "b_pair" / "sparse.tif")
    info = cli_json(["block", str(copy / "cluster.yaml"), "-o", str(out), "--workers", "0", "--json"])
    assert statuses(info) == {"a": "skipped", "b_pair": "done", "c": "skipped", "d_pair": "skipped"}
    assert info["merged"]["status"] == "done"
    for name in ("a", "c", "d_pair"):
        assert output_hashes(out, name) == output_hashes(block / "seq", name)
    # the new disparities are the new image's (match_tiled on it, as the block's tiles compute it), not the old ones
    got = read_disparity(out / "pairs" / "b_pair" / "disparity.tif")
    sparse = read_disparity(out / "pairs" / "b_pair" / "sparse.tif")
    want = match_tiled(read_image(pair.left), read_image(pair.right), sparse, tile=128, overlap=32).disparity
    np.testing.assert_array_equal(got, want)
    assert not np.array_equal(got, before, equal_nan=True)
    np.testing.assert_array_equal(sparse, sparse_before)  # same cloud, same projection
    new, old = output_hashes(out, "b_pair"), output_hashes(block / "seq", "b_pair")
    assert all(new[k] != old[k] for k in ("disparity.tif", "points.laz", "dsm.tif"))
    assert not np.array_equal(read_dsm(out / "dsm.tif")[0], read_dsm(block / "seq" / "dsm.tif")[0], equal_nan=True)


def test_changed_cloud_reruns_its_pair_only(block, tmp_path):
    copy = copy_block(block, tmp_path)
    out = copy / "seq"
    xyz = read_lidar(copy / "own" / "a.laz")["xyz"]
    kept = xyz[::2]  # every other point
    write_points(copy / "own" / "a.laz", kept, None, CRS, overwrite=True)
    info = cli_json(["block", str(copy / "cluster.yaml"), "-o", str(out), "--workers", "0", "--json"])
    assert statuses(info) == {"a": "done", "b_pair": "skipped", "c": "skipped", "d_pair": "skipped"}
    assert info["merged"]["status"] == "done"
    for name in ("b_pair", "c", "d_pair"):
        assert output_hashes(out, name) == output_hashes(block / "seq", name)
    stats = json.loads((out / "pairs" / "a" / "done.json").read_text())["stats"]
    assert stats["lidar_points_read"] == len(kept)
    # the new sparse disparities are riverbed project's of the new cloud, and differ from the old ones
    res = CliRunner().invoke(cli, ["project", str(copy / "own" / "a.laz"), str(copy / "a" / "pair.yaml"), "-o",
                                   str(tmp_path / "a.tif")], catch_exceptions=False)
    assert res.exit_code == 0, res.stderr
    got = read_disparity(out / "pairs" / "a" / "sparse.tif")
    projected = read_disparity(tmp_path / "a.tif")
    # sparse.tif holds the points the LiDAR check kept (the dropped ones counted in the pair's stats)
    dropped = stats["lidar_check"]["outliers"] + stats["lidar_check"]["changed"]
    assert np.isfinite(projected).sum() - np.isfinite(got).sum() == dropped
    kept = np.isfinite(got)
    np.testing.assert_array_equal(got[kept], projected[kept])
    assert np.isfinite(got).sum() < np.isfinite(read_disparity(block / "seq" / "pairs" / "a" / "sparse.tif")).sum()
    new, old = output_hashes(out, "a"), output_hashes(block / "seq", "a")
    assert all(new[k] != old[k] for k in new)  # every product of the pair follows the new cloud


# -- --workers and --threads-per-worker -----------------------------------------------------------------------------

def test_workers_and_threads_per_worker_reach_the_local_cluster(block, tmp_path):
    """``--workers 1 --threads-per-worker 2`` (both off their defaults on two cores): the cluster the block starts
    has one worker with two threads, and each task sets CPUs // (1 x 2) Numba threads."""
    base = block
    manifest = yaml.safe_load((base / "cluster.yaml").read_text())
    manifest["pairs"] = manifest["pairs"][3:]  # d_pair: one task
    (base / "one.yaml").write_text(yaml.safe_dump(manifest, sort_keys=False))
    info = cli_json(["block", str(base / "one.yaml"), "-o", str(tmp_path / "out"), "--workers", "1",
                     "--threads-per-worker", "2", "--json"])
    per_task = max(1, os.cpu_count() // 2)
    assert info["mode"] == "local" and statuses(info) == {"d_pair": "done"}
    assert {k: v for k, v in info["cluster"].items() if k != "scheduler"} == {
        "workers": 1, "threads_per_worker": [2], "numba_threads": per_task}
    assert info["cluster"]["scheduler"].startswith("tcp://127.0.0.1:")
    assert info["pairs"][0]["numba_threads"] == min(per_task, numba.config.NUMBA_NUM_THREADS)
    assert output_hashes(tmp_path / "out", "d_pair") == output_hashes(base / "seq", "d_pair")
