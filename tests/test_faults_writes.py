"""Fault injection on riverbed's outputs: a write that fails is a failure.

Every subcommand that writes is run in a real process with a file-size limit (``RLIMIT_FSIZE``, what ``ulimit -f``
sets; a full disk fails the same ``write``), over an output the user already had, with ``--overwrite``: it must exit
1 with one line naming the output, leave the old file byte for byte, and leave no temporary file. Then: a kill
mid-write, a second run on the same output or block folder, an output that is one of the inputs or another output,
outputs that must appear together, and a long output name.
"""

import os
import re
import resource
import shutil
import signal
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest

from riverbed_cli.errors import RiverbedError
from riverbed_cli.io.atomic import (TEMP_NAME, atomic_output, check_output, lock_folder, output_group,
                                    release_claims, temporary_name, unlock_folder)
from test_cli_project import CALIB as MIDDLEBURY_CALIB
from conftest import RIVERBED

REPO = Path(__file__).resolve().parents[1]
REINDEER = REPO / "sample_data" / "reindeer"
BLOCK = REPO / "sample_data" / "block"
LEFT, RIGHT, SPARSE, GT = (str(REINDEER / n) for n in ("left.png", "right.png", "lidar_5pct.tif", "gt.png"))
INCOMPLETE = "cannot write: the file written is incomplete (is the disk full, or a file-size limit set?)"
TOO_LARGE = "cannot write (file too large for the file-size limit or the file system)"


def riverbed(*args, cwd=None, fsize=None, check=None, timeout=300):
    """``riverbed ARGS`` in a process of its own (optionally under a file-size limit in bytes)."""

    def limit():
        if fsize is not None:
            resource.setrlimit(resource.RLIMIT_FSIZE, (fsize, fsize))

    r = subprocess.run([*RIVERBED, *map(str, args)], cwd=cwd, capture_output=True,
                       text=True, preexec_fn=limit, timeout=timeout)
    if check is not None:
        assert r.returncode == check, r.stderr
    return r


def temporaries(folder):
    """riverbed's temporary files anywhere under ``folder``."""
    return sorted(str(p.relative_to(folder)) for p in Path(folder).rglob(".*") if TEMP_NAME.match(p.name))


def snapshot(paths):
    return {str(p): Path(p).read_bytes() for p in paths}


# -- a write that fails: every subcommand that writes ---------------------------------------------------------------

@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    """Small inputs: the sample block's sparse map and disparity (for range-map, densify, dsm, evaluate)."""
    d = tmp_path_factory.mktemp("inputs")
    riverbed("project", BLOCK / "lidar.laz", BLOCK / "pair.yaml", "-o", d / "sparse.tif", check=0)
    riverbed("match", BLOCK / "left.png", BLOCK / "right.png", "--sparse", d / "sparse.tif", "-o", d / "disp.tif",
             check=0)
    (d / "calib.txt").write_text(MIDDLEBURY_CALIB)  # a Middlebury calibration (tests/test_cli_project.py)
    shutil.copytree(REPO / "tests" / "data" / "cones", d / "mb" / "cones")  # a Middlebury-layout benchmark set
    return d


def _cases(i):
    """(name, argv with {out}, outputs relative to the run folder, the message's problem, limit in bytes)."""
    b = BLOCK
    return [
        ("match .tif", ["match", LEFT, RIGHT, "--sparse", SPARSE, "-o", "{out}/d.tif"], ["d.tif"], INCOMPLETE, 4096),
        ("match .tif tiled", ["match", LEFT, RIGHT, "--sparse", SPARSE, "-o", "{out}/d.tif", "--tile", "192"],
         ["d.tif"], INCOMPLETE, 4096),
        ("match .pfm", ["match", LEFT, RIGHT, "--sparse", SPARSE, "-o", "{out}/d.pfm"], ["d.pfm"], TOO_LARGE, 4096),
        ("match .png", ["match", LEFT, RIGHT, "--sparse", SPARSE, "-o", "{out}/d.png"], ["d.png"], TOO_LARGE, 4096),
        ("match --confidence", ["match", LEFT, RIGHT, "--sparse", SPARSE, "-o", "{out}/d.pfm", "--confidence",
                                "{out}/c.tif"], ["d.pfm", "c.tif"], None, 4096),
        ("match --color", ["match", LEFT, RIGHT, "--sparse", SPARSE, "-o", "{out}/d.pfm", "--color", "{out}/c.png"],
         ["d.pfm", "c.png"], None, 4096),
        ("range-map", ["range-map", i / "disp.tif", "-o", "{out}/r.tif"], ["r.tif"], INCOMPLETE, 4096),
        ("densify", ["densify", i / "sparse.tif", "-o", "{out}/l.tif"], ["l.tif"], INCOMPLETE, 4096),
        ("project", ["project", b / "lidar.laz", b / "pair.yaml", "-o", "{out}/s.tif"], ["s.tif"], INCOMPLETE, 4096),
        ("dsm + points + hillshade", ["dsm", i / "disp.tif", b / "pair.yaml", "-o", "{out}/dsm.tif", "--points",
                                      "{out}/p.laz", "--hillshade", "{out}/h.png"],
         ["dsm.tif", "p.laz", "h.png"], None, 4096),
        ("evaluate --error-map", ["evaluate", i / "disp.tif", b / "gt_disparity.tif", "--error-map", "{out}/e.png"],
         ["e.png"], TOO_LARGE, 4096),
        ("pair", ["pair", "middlebury", i / "calib.txt", "-o", "{out}/p.yaml"], ["p.yaml"],
         TOO_LARGE, 64),
        ("rectify", ["rectify", b / "raw/frame0.png", b / "raw/frame0.yaml", b / "raw/frame1.png",
                     b / "raw/frame1.yaml", "-o", "{out}/rect"], ["rect/left.png", "rect/right.png", "rect/pair.yaml"],
         None, 4096),
        # results files are rewritten by every run (its cache resumes it): no --overwrite; the cases come from the
        # first run's cache, so only the tables are written
        ("benchmark", ["benchmark", i / "mb", "--layout", "middlebury", "-o", "{out}/bench", "--guides", "none",
                       "--shares", "0.05", "--baselines", ""],
         ["bench/results.csv", "bench/results.json", "bench/results.md"], TOO_LARGE, 64),
    ]


CASE_NAMES = [c[0] for c in _cases(Path("."))]


@pytest.mark.parametrize("name", CASE_NAMES)
def test_a_failed_write_exits_1_and_keeps_the_old_output(inputs, tmp_path, name):
    """The old outputs stay byte for byte, one line names an output, exit 1, no temporary file is left."""
    _, argv, outputs, problem, limit = next(c for c in _cases(inputs) if c[0] == name)
    args = [str(a).replace("{out}", str(tmp_path)) for a in argv]
    riverbed(*args, check=0)  # the user's good outputs (and the kernels this run loads, compiled and cached)
    old = snapshot(tmp_path / o for o in outputs)
    r = riverbed(*args, "--overwrite", fsize=limit)
    assert r.returncode == 1, r.stderr
    lines = r.stderr.splitlines()
    assert len(lines) == 1, r.stderr
    named = [o for o in outputs if lines[0].startswith(f"riverbed: error: {tmp_path / o}: ")]
    assert named, lines[0]
    if problem is not None:
        assert lines[0] == f"riverbed: error: {tmp_path / named[0]}: {problem}"
    else:
        assert re.fullmatch(rf"riverbed: error: {re.escape(str(tmp_path / named[0]))}: "
                            rf"({re.escape(INCOMPLETE)}|{re.escape(TOO_LARGE)}|cannot write point cloud .*)",
                            lines[0]), lines[0]
    assert snapshot(tmp_path / o for o in outputs) == old
    assert temporaries(tmp_path) == []


# -- a kill mid-write, then the next run ----------------------------------------------------------------------------

def test_a_killed_run_keeps_the_old_output_and_the_next_run_removes_its_temporary(tmp_path):
    """SIGKILL while a tiled match streams its tiles into the temporary file: the old output is intact, the
    temporary file is left; the next run (another output in the same folder) removes it."""
    out = tmp_path / "d.tif"
    args = ["match", LEFT, RIGHT, "--sparse", SPARSE, "-o", out, "--tile", "64", "--overlap", "16"]
    riverbed(*args, check=0)
    old = out.read_bytes()
    tmp = temporary_name(out)
    proc = subprocess.Popen([*RIVERBED, *map(str, args), "--overwrite"],
                            stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 120
        while not (tmp.exists() and tmp.stat().st_size > 0):  # tiles are being written
            assert proc.poll() is None, "the match ended before it could be killed"
            assert time.monotonic() < deadline
            time.sleep(0.005)
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert out.read_bytes() == old
    assert temporaries(tmp_path) == [tmp.name]
    riverbed("range-map", out, "-o", tmp_path / "r.tif", check=0)
    assert temporaries(tmp_path) == []
    assert out.read_bytes() == old


# -- concurrent runs --------------------------------------------------------------------------------------------------

def test_a_second_run_on_an_output_being_written_is_refused(tmp_path):
    """While a run holds an output (here this process, as a first riverbed run would), a second says so in one line
    and writes nothing; once it is released the second runs."""
    out = tmp_path / "d.tif"
    check_output(out)
    try:
        r = riverbed("match", LEFT, RIGHT, "--max-disp", "40", "-o", out)
        assert r.returncode == 1
        assert r.stderr == (f"riverbed: error: {out}: in use by another riverbed run (it is being written); wait for "
                            "that run or choose another output\n")
        assert not out.exists()
    finally:
        release_claims([out])
    assert temporaries(tmp_path) == []
    riverbed("match", LEFT, RIGHT, "--max-disp", "40", "-o", out, check=0)


def test_two_runs_started_together_write_one_output_once(tmp_path):
    """Two real runs to one new output without --overwrite: one writes it, the other fails in one line (in use, or
    the output exists) and nothing is replaced."""
    out = tmp_path / "d.tif"
    args = [*RIVERBED, "match", LEFT, RIGHT, "--max-disp", "120", "-o", str(out)]
    procs = [subprocess.Popen(args, stderr=subprocess.PIPE, text=True) for _ in range(2)]
    results = [(p.wait(timeout=300), p.stderr.read()) for p in procs]
    codes = sorted(rc for rc, _ in results)
    assert codes == [0, 1], results
    err = next(e for rc, e in results if rc == 1)
    assert err in (f"riverbed: error: {out}: in use by another riverbed run (it is being written); wait for that run "
                   "or choose another output\n",
                   f"riverbed: error: {out}: output exists; pass --overwrite to replace it\n"), err
    assert temporaries(tmp_path) == []


def test_a_second_block_on_a_folder_in_use_is_refused(tmp_path):
    manifest = tmp_path / "m.yaml"
    manifest.write_text(f"pairs:\n  - {{pair: {BLOCK / 'pair.yaml'}, cloud: {BLOCK / 'lidar.laz'}}}\n")
    out = tmp_path / "out"
    out.mkdir()
    lock_folder(out)  # as a first riverbed block on it does
    try:
        r = riverbed("block", manifest, "-o", out, "--workers", "0")
        assert r.returncode == 1
        assert r.stderr == (f"riverbed: error: {out}: in use by another riverbed run (it is writing into this "
                            "folder); wait for that run or choose another output folder\n")
        assert sorted(p.name for p in out.iterdir()) == [".riverbed.lock"]
    finally:
        unlock_folder(out)


# -- an output that is an input, or two outputs in one file ----------------------------------------------------------

def _copy(src, dst):
    shutil.copy(src, dst)
    return dst


@pytest.mark.parametrize("case", ["match -o LEFT", "match --color LEFT", "range-map -o DISP",
                                  "evaluate --error-map GT", "densify -o SPARSE", "dsm --points CLOUD via link"])
def test_an_output_that_is_an_input_is_refused_before_the_work(tmp_path, case):
    left = _copy(LEFT, tmp_path / "left.png")
    sparse = _copy(SPARSE, tmp_path / "sparse.tif")
    gt = _copy(GT, tmp_path / "gt.png")
    if case == "match -o LEFT":
        args, target = ["match", left, RIGHT, "--max-disp", "40", "-o", left], left
    elif case == "match --color LEFT":
        args, target = ["match", left, RIGHT, "--max-disp", "40", "-o", tmp_path / "d.tif", "--color", left], left
    elif case == "range-map -o DISP":
        args, target = ["range-map", sparse, "-o", sparse, "--min-disp", "0", "--max-disp", "60"], sparse
    elif case == "evaluate --error-map GT":
        args, target = ["evaluate", sparse, gt, "--gt-scale", "2", "--error-map", gt], gt
    elif case == "densify -o SPARSE":
        args, target = ["densify", sparse, "-o", sparse], sparse
    else:
        cloud = _copy(BLOCK / "lidar.laz", tmp_path / "lidar.laz")
        os.symlink(cloud, tmp_path / "link.laz")  # the same file under another name
        args = ["dsm", "--lidar", cloud, "-o", tmp_path / "dsm.tif", "--points", tmp_path / "link.laz"]
        target = tmp_path / "link.laz"
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir() if p.is_file()}
    r = riverbed(*args, "--overwrite")
    assert r.returncode == 1, r.stderr
    source = target if case != "dsm --points CLOUD via link" else tmp_path / "lidar.laz"
    assert r.stderr == (f"riverbed: error: {target}: is also an input of this run ({source}); riverbed never writes "
                        "over its input\n")
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir() if p.is_file()} == before
    assert temporaries(tmp_path) == []


def test_two_outputs_in_one_file_are_refused(tmp_path):
    out = tmp_path / "d.tif"
    r = riverbed("match", LEFT, RIGHT, "--sparse", SPARSE, "-o", out, "--confidence", f"{tmp_path}/./d.tif")
    assert r.returncode == 1
    assert r.stderr == f"riverbed: error: {out}: given twice as an output of this run\n"
    assert list(tmp_path.iterdir()) == []


# -- outputs written together, a file that appears meanwhile, long names ---------------------------------------------

def test_outputs_of_a_group_appear_together_or_not_at_all(tmp_path):
    a, b = tmp_path / "a.txt", tmp_path / "b.txt"
    a.write_text("old a")
    with pytest.raises(RiverbedError, match="b.txt: cannot write"):
        with output_group():
            with atomic_output(a, overwrite=True) as t:
                t.write_text("new a")
            with atomic_output(b) as t:
                raise OSError(28, "No space left on device")
    assert a.read_text() == "old a" and not b.exists()
    assert temporaries(tmp_path) == []
    with output_group():
        for p, text in ((a, "new a"), (b, "new b")):
            with atomic_output(p, overwrite=True) as t:
                t.write_text(text)
        assert a.read_text() == "old a"  # not yet: renamed when the group ends
    assert (a.read_text(), b.read_text()) == ("new a", "new b")
    assert temporaries(tmp_path) == []


def test_a_file_that_appears_meanwhile_is_not_replaced_without_overwrite(tmp_path):
    out = tmp_path / "o.txt"
    with pytest.raises(RiverbedError) as e:
        with atomic_output(out) as t:
            t.write_text("mine")
            out.write_text("someone else's")
    assert str(e.value) == (f"{out}: output exists (written meanwhile by something else); pass --overwrite to "
                            "replace it")
    assert out.read_text() == "someone else's"
    assert temporaries(tmp_path) == []


def test_errors_name_the_output_never_the_temporary(tmp_path):
    out = tmp_path / "o.txt"
    with pytest.raises(RiverbedError) as e:
        with atomic_output(out) as t:
            raise RiverbedError("broken", t)
    assert str(e.value) == f"{out}: broken"


def test_an_output_name_of_251_bytes_is_written(tmp_path):
    """The temporary name never exceeds the 255-byte file-name limit when the output's own name does not."""
    out = tmp_path / ("n" * 247 + ".tif")
    assert len(out.name) == 251 and len(temporary_name(out).name.encode()) <= 255
    riverbed("match", LEFT, RIGHT, "--max-disp", "40", "-o", out, check=0)
    assert out.stat().st_size > 0 and temporaries(tmp_path) == []


def test_temporary_names_are_fixed_by_the_output_and_match_the_cleaners_pattern(tmp_path):
    t = temporary_name(tmp_path / "disparity.tif")
    assert t == temporary_name(tmp_path / "disparity.tif") != temporary_name(tmp_path / "disparity2.tif")
    assert re.fullmatch(r"\.disparity\.[0-9a-f]{8}\.tmp\.tif", t.name) and TEMP_NAME.match(t.name)
    assert np.all([TEMP_NAME.match(temporary_name(tmp_path / n).name) for n in ("a", "b.laz", "x" * 300 + ".png")])


def test_a_block_whose_writes_fail_reports_each_pair_in_one_line_and_leaves_no_temporary(tmp_path):
    manifest = tmp_path / "m.yaml"
    manifest.write_text(f"pairs:\n  - {{pair: {BLOCK / 'pair.yaml'}, cloud: {BLOCK / 'lidar.laz'}, name: s}}\n")
    out = tmp_path / "out"
    r = riverbed("block", manifest, "-o", out, "--workers", "0", fsize=4096)
    assert r.returncode == 1
    assert r.stderr.splitlines() == [
        f"riverbed: error: pair s failed in project: {out}/pairs/s/sparse.tif: {INCOMPLETE}",
        "riverbed: error: merged DSM: no pair finished: no merged DSM"]
    assert temporaries(tmp_path) == []


def test_a_staging_folder_names_the_final_files_and_replaces_a_killed_runs(tmp_path):
    from riverbed_cli.io.atomic import staging_folder

    out = tmp_path / "sample"
    stale, live = tmp_path / ".sample.abcd1234.tmp", tmp_path / ".sample.live0000.tmp"
    stale.mkdir()
    live.mkdir()
    lock_folder(live)  # a run still writing there
    try:
        with pytest.raises(RiverbedError) as e:
            with staging_folder(out) as tmp:
                assert tmp.parent == tmp_path and tmp.name.startswith(".sample.")
                raise RiverbedError("cannot write (no space left on the device)", tmp / "left.png")
        assert str(e.value) == f"{out / 'left.png'}: cannot write (no space left on the device)"
        assert sorted(p.name for p in tmp_path.iterdir()) == [live.name]
    finally:
        unlock_folder(live)
