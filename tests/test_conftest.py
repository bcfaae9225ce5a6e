"""The data tests' set-up: the shared folder found by itself, skipped on a bare clone, required under CI."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

from conftest import find_shared_data, missing_data_outcome

TESTS = Path(__file__).parent


def test_the_shared_folder_is_found(tmp_path):
    data = tmp_path / "shared" / "data"
    data.mkdir(parents=True)
    repo = tmp_path / "main"
    repo.mkdir()
    assert find_shared_data({"RIVERBED_DATA": str(data)}, repo) == data
    assert find_shared_data({"RIVERBED_DATA": str(tmp_path / "nope")}, repo) is None
    assert find_shared_data({}, repo) == data  # ../shared/data beside the clone
    assert find_shared_data({}, tmp_path / "elsewhere" / "main") is None
    assert missing_data_outcome({"CI": "true"}) == "fail"
    assert missing_data_outcome({}) == "skip" and missing_data_outcome({"CI": "false"}) == "skip"


def _run(env):
    env = {k: v for k, v in os.environ.items() if k not in ("RIVERBED_DATA", "CI")} | env
    return subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-rs",
                           str(TESTS / "test_dsm_real.py")], capture_output=True, text=True, env=env,
                          cwd=TESTS.parent)


def test_data_tests_skip_on_a_bare_clone_and_fail_under_ci():
    bare = _run({"RIVERBED_DATA": "/nonexistent/shared/data"})
    assert bare.returncode == 0, bare.stdout[-2000:]
    assert "skipped" in bare.stdout and "RIVERBED_DATA=/nonexistent/shared/data is not a folder" in bare.stdout
    ci = _run({"RIVERBED_DATA": "/nonexistent/shared/data", "CI": "true"})
    assert ci.returncode == 1 and "CI runs every data test" in ci.stdout


def test_a_skip_under_ci_fails_unless_it_names_a_missing_capability(monkeypatch):
    from types import SimpleNamespace

    import conftest

    for ci, reason, outcome in (("true", "needs the grid", "failed"), ("true", "capability: no AVX2", "skipped"),
                                ("", "needs the grid", "skipped")):
        monkeypatch.setenv("CI", ci)
        report = SimpleNamespace(skipped=True, longrepr=("t.py", 1, f"Skipped: {reason}"), outcome="skipped")
        hook = conftest.pytest_runtest_makereport(None, None)
        next(hook)
        with pytest.raises(StopIteration):
            hook.send(SimpleNamespace(get_result=lambda: report))
        assert report.outcome == outcome, (ci, reason)
        if outcome == "failed":
            assert report.longrepr == ("skipped under CI (only a missing machine capability may skip there): "
                                       "Skipped: needs the grid")
