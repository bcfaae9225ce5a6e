"""The garbage collector of the ``riverbed`` program (riverbed_cli/runtime/collector.py): off while a command starts up,
on again with start-up's objects frozen, everything frozen for the exit; untouched outside the program."""

import gc
import json
import os
import subprocess
from pathlib import Path

import pytest

from riverbed_cli.products.simulate import simulate_lidar
from riverbed_cli.io.disparity import write_disparity
from riverbed_cli.runtime import collector
from conftest import PYTHON

DATA = Path(__file__).parent / "data" / "cones"
LEFT, RIGHT = str(DATA / "im2.png"), str(DATA / "im6.png")

# run the program's entry point; at exit (after main's own exit steps) report the collector's state
_PROBE = """
import atexit, gc, sys
from riverbed_cli.__main__ import main
atexit.register(lambda: print(f"frozen {gc.get_freeze_count()} enabled {gc.isenabled()}", file=sys.stderr))
main(sys.argv[1:])
"""


@pytest.fixture()
def restore_collector():
    yield
    gc.unfreeze()
    gc.enable()
    collector._STATE.update(program=False, paused=False)


def test_library_use_leaves_the_collector_alone(restore_collector):
    frozen = gc.get_freeze_count()
    assert not collector.pause_for_start_up()
    assert gc.isenabled()
    collector.start_up_done()
    collector.freeze_for_exit()
    assert gc.isenabled() and gc.get_freeze_count() == frozen


def test_program_pauses_start_up_then_freezes(restore_collector, monkeypatch):
    monkeypatch.delenv("RIVERBED_GC", raising=False)
    gc.unfreeze()
    with collector.program():
        assert collector.pause_for_start_up()
        assert not gc.isenabled()
        assert not collector.pause_for_start_up()  # once
        alive = [object() for _ in range(10)]
        collector.start_up_done()
        assert gc.isenabled()
        after_start_up = gc.get_freeze_count()
        assert after_start_up > 0
        more = [[] for _ in range(1000)]
    assert gc.get_freeze_count() >= after_start_up + len(more) - 50  # the exit froze what the run made since
    assert alive and more


def test_program_with_riverbed_gc_default_changes_nothing(restore_collector, monkeypatch):
    monkeypatch.setenv("RIVERBED_GC", "default")
    gc.unfreeze()
    with collector.program():
        assert not collector.pause_for_start_up()
        assert gc.isenabled()
    assert gc.get_freeze_count() == 0


def _probe(args, tmp_path, **env):
    p = subprocess.run([*PYTHON, "-c", _PROBE, *args], capture_output=True, text=True, timeout=600,
                       env={**os.environ, **env}, cwd=tmp_path)
    *lines, state = p.stderr.strip().splitlines()
    return p, lines, state.split()


def test_match_process_exits_with_its_objects_frozen_and_collector_on(tmp_path, cones):
    write_disparity(tmp_path / "sparse.tif", simulate_lidar(cones[2], 0.05, seed=0))
    out = tmp_path / "d.tif"
    args = ["match", LEFT, RIGHT, "--sparse", str(tmp_path / "sparse.tif"), "-o", str(out), "--json"]
    p, lines, state = _probe(args, tmp_path)
    assert p.returncode == 0 and lines == []
    assert json.loads(p.stdout)["output"] == str(out) and out.exists()
    assert int(state[1]) > 10_000 and state[3] == "True"  # Numba's, NumPy's, riverbed's objects frozen; gc back on
    # an error before the kernels load: the same one-line message and exit code, the collector left paused
    p, lines, state = _probe(["match", "nope.png", RIGHT, "--max-disp", "9", "-o", str(tmp_path / "x.tif")],
                             tmp_path)
    assert p.returncode == 1 and lines == ["riverbed: error: nope.png: file not found"]
    assert int(state[1]) > 0 and state[3] == "False"
    # another command: its start-up ends once its module is imported (cli.main.RiverbedGroup), errors or not
    p, lines, state = _probe(["evaluate", "nope.tif", "nope.tif"], tmp_path)
    assert p.returncode == 1 and lines == ["riverbed: error: nope.tif: file not found"]
    assert int(state[1]) > 10_000 and state[3] == "True"
    # RIVERBED_GC=default: as Python has it
    p, lines, state = _probe(args + ["--overwrite"], tmp_path, RIVERBED_GC="default")
    assert p.returncode == 0 and state[1:] == ["0", "enabled", "True"]
