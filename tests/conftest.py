import os
import sys
from pathlib import Path

from riverbed_cli.runtime import Env

#: The tests run with the process settings of the ``riverbed`` program (riverbed_cli.runtime), as a program that
#: imports riverbed opts in to them, entered before any kernel module is imported (Numba reads its cache folder as
#: each is); the processes the tests start inherit its environment variables.
ENV = Env().__enter__()

import numpy as np  # noqa: E402
import pytest  # noqa: E402

from riverbed_cli.io.disparity import read_disparity  # noqa: E402
from riverbed_cli.io.images import read_image  # noqa: E402

DATA = Path(__file__).parent / "data"

#: this interpreter, for a process of its own that imports the riverbed these tests import: ``-P`` keeps the working
#: directory off the child's path, where a checkout beside a non-editable install (CI's) would be imported instead,
#: its kernels compiled apart in a cache folder of their own (one per copy: numba_cache.cache_dir)
PYTHON = (sys.executable, "-P") if sys.version_info >= (3, 11) else (sys.executable,)
#: ``riverbed`` in a process of its own (``python -m riverbed_cli``)
RIVERBED = (*PYTHON, "-m", "riverbed_cli")


def pytest_unconfigure(config):
    ENV.__exit__(None, None, None)


@pytest.fixture(scope="session")
def cones():
    """Middlebury 2003 Cones, quarter size (450x375): left, right, GT (d = value / 4, NaN unknown)."""
    base = DATA / "cones"
    return read_image(base / "im2.png"), read_image(base / "im6.png"), read_disparity(base / "disp2.png", scale=4)


REPO = Path(__file__).resolve().parents[1]
NO_DATA = ("needs the shared real-data folder (KITTI, the aerial pair, LAS corpora; not in the repository): set "
           "RIVERBED_DATA to it, or put it at ../shared/data beside the clone")


def find_shared_data(environ=os.environ, repo=REPO):
    """The shared real-data folder: ``RIVERBED_DATA`` when set, else ``../shared/data`` beside the clone when it is
    there, else None."""
    path = environ.get("RIVERBED_DATA")
    if path:
        return Path(path) if Path(path).is_dir() else None
    beside = repo.parent / "shared" / "data"
    return beside if beside.is_dir() else None


def missing_data_outcome(environ=os.environ):
    """What a data test does without the data: ``fail`` under CI (``CI`` set, as ``.ci/run`` does: CI must run every
    test), ``skip`` elsewhere (a newcomer's first run of the README's test command passes)."""
    return "fail" if environ.get("CI", "").lower() not in ("", "0", "false") else "skip"


#: the start of a skip reason that names a capability the machine (or its installed packages) lacks: the only skip CI
#: accepts; any other skip under CI is a failure (a skip must not stand in for a feature)
CAPABILITY = "capability: "


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    outcome = yield
    report = outcome.get_result()
    if report.skipped and missing_data_outcome() == "fail" and not hasattr(report, "wasxfail"):
        reason = report.longrepr[2] if isinstance(report.longrepr, tuple) else str(report.longrepr)
        if CAPABILITY not in reason:
            report.outcome = "failed"
            report.longrepr = f"skipped under CI (only a missing machine capability may skip there): {reason}"


def pytest_collection_modifyitems(config, items):
    # every test that reads the shared data carries the `data` marker: `pytest -m "not data"` runs exactly the
    # tests that need nothing outside the repository
    for item in items:
        if "shared_data" in getattr(item, "fixturenames", ()):
            item.add_marker(pytest.mark.data)


@pytest.fixture(scope="session")
def shared_data():
    """The shared real-data folder (KITTI etc., not in the repository): :func:`find_shared_data`."""
    path = find_shared_data()
    if path is None:
        where = os.environ.get("RIVERBED_DATA")
        reason = f"RIVERBED_DATA={where} is not a folder" if where else NO_DATA
        if missing_data_outcome() == "fail":
            pytest.fail(f"{reason} (CI runs every data test)")
        pytest.skip(reason)
    return path


def rng():
    return np.random.default_rng(12345)


EGM96_MISSING = ("needs PROJ's EGM96 geoid grid (Debian's proj-data, which .ci/run installs; pyproj's wheel ships no "
                 "grids)")


@pytest.fixture(scope="session")
def egm96():
    """PROJ's EGM96 -> WGS 84 ellipsoid transformer; without the grid the test is skipped with the reason, and fails
    under CI (``.ci/run`` installs the grid, so the geoid path is always tested there)."""
    from riverbed_cli.errors import RiverbedError
    from riverbed_cli.geometry.rpc_dem import EGM96, geoid_to_ellipsoid_transformer

    try:
        return geoid_to_ellipsoid_transformer(EGM96)
    except RiverbedError as e:
        if missing_data_outcome() == "fail":
            pytest.fail(f"{EGM96_MISSING}: {e}")
        pytest.skip(EGM96_MISSING)


@pytest.fixture
def no_egm96_grid(monkeypatch):
    """A PROJ that finds no geoid grid (its own data folder only, Debian's not added): the missing-grid path, on any
    machine."""
    import pyproj.datadir

    from riverbed_cli.geometry import rpc_dem

    before = pyproj.datadir.get_data_dir()
    own = [d for d in before.split(":") if d and d != str(rpc_dem.SYSTEM_PROJ_DATA)]
    pyproj.datadir.set_data_dir(own[0] if own else before)
    monkeypatch.setattr(rpc_dem, "SYSTEM_PROJ_DATA", rpc_dem.Path("/nonexistent/proj"))
    try:
        yield
    finally:
        pyproj.datadir.set_data_dir(before)
