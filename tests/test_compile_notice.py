"""The first run says it compiles (issue: a first `riverbed match` compiled for ~50 s with no word on the terminal)."""

import io

import pytest

from riverbed_cli.runtime import numba_cache as cached_kernels


class _Terminal(io.StringIO):
    def isatty(self):
        return True


@pytest.fixture
def fresh(monkeypatch):
    monkeypatch.setattr(cached_kernels, "_ANNOUNCED", [])
    return cached_kernels


def test_a_cache_miss_is_announced_once_on_a_terminal(fresh, monkeypatch):
    err = _Terminal()
    monkeypatch.setattr("sys.stderr", err)

    class Cache:  # what the patched Cache.load_overload calls: a miss, then a hit
        results = [None, "kernel"]

        def _guard_against_spurious_io_errors(self):
            import contextlib
            return contextlib.nullcontext()

        def _load_overload(self, sig, target_context):
            return self.results.pop(0)

    from numba.core import caching

    if not fresh.skip_refresh_on_cache_loads():
        pytest.skip("capability: this Numba lacks the methods riverbed's start-up patch relies on (it leaves Numba as it is)")
    load = caching.Cache.load_overload
    monkeypatch.setattr("numba.core.runtime.rtsys.initialize", lambda ctx: None)
    assert load(Cache(), None, None) is None and load(Cache(), None, None) == "kernel"
    fresh.announce_compiling()
    assert err.getvalue() == ("riverbed: compiling riverbed's kernels for this machine (the first run after installing; "
                              "cached for the next)\n")


def test_in_a_pipe_it_is_a_log_line(fresh, monkeypatch, caplog):
    err = io.StringIO()
    monkeypatch.setattr("sys.stderr", err)
    with caplog.at_level("INFO", logger=cached_kernels.__name__):
        fresh.announce_compiling()
    assert err.getvalue() == "" and caplog.messages == [
        "compiling riverbed's kernels for this machine (the first run after installing; cached for the next)"]
