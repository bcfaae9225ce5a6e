"""What riverbed does to its process, in one place (riverbed_cli.runtime): nothing at import, the program's settings
inside its Env, restored when it exits."""

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from riverbed_cli import runtime
from riverbed_cli.runtime import Env
from conftest import PYTHON

PACKAGE = Path(runtime.__file__).parents[1]

#: the variables riverbed's Env sets (and a test process inherits from this session's Env)
OURS = ("OMP_WAIT_POLICY", "GOMP_SPINCOUNT", "RIVERBED_OMP_DEFAULT", "NUMPY_MADVISE_HUGEPAGE", "NUMBA_CACHE_DIR")

# import every module of the package, then report what changed in the process: environment variables, the
# collector, Numba's cache loading, and whether glibc keeps a freed 64 MiB array (malloc's thresholds)
IMPORT_ALL = """
import gc, importlib, json, os, pkgutil, sys
import cv2  # OpenCV's loader sets LD_LIBRARY_PATH on import: another package's doing, taken out of the comparison
before = dict(os.environ)
frozen, enabled = gc.get_freeze_count(), gc.isenabled()
import riverbed_cli
names = sorted(m.name for m in pkgutil.walk_packages(riverbed_cli.__path__, "riverbed_cli."))
for name in names:
    importlib.import_module(name)
from numba.core import caching
import numpy as np
def rss():
    return int(open("/proc/self/statm").read().split()[1]) * os.sysconf("SC_PAGE_SIZE") >> 20
a = np.ones(64 << 17)
held = rss()
del a
changed = sorted(k for k in set(before) | set(os.environ) if before.get(k) != os.environ.get(k))
print(json.dumps({"modules": len(names), "changed": changed, "freeze": gc.get_freeze_count() - frozen,
                  "gc": gc.isenabled() == enabled, "numba": caching.Cache.load_overload.__module__,
                  "kept": held - rss() < 16}))
"""


def clean_environ():
    return {k: v for k, v in os.environ.items() if k not in OURS and not k.startswith(("MALLOC_", "GLIBC_TUNABLES"))}


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's malloc and /proc")
def test_importing_every_module_changes_nothing_in_the_process():
    out = subprocess.run([*PYTHON, "-c", IMPORT_ALL], env=clean_environ(), capture_output=True, text=True,
                         check=True)
    res = json.loads(out.stdout)
    # every module but the package itself (imported first)
    assert res["modules"] == len(list(PACKAGE.rglob("*.py"))) - 1  # __main__ and the runtime included
    assert res == {"modules": res["modules"], "changed": [], "freeze": 0, "gc": True, "numba": "numba.core.caching",
                   "kept": False}


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's malloc and /proc")
def test_the_env_sets_what_the_program_runs_with_and_restores_the_variables():
    code = IMPORT_ALL.replace("import riverbed_cli\n", "import riverbed_cli\nfrom riverbed_cli.runtime import Env, "
                              "before_kernels\nenv = Env().__enter__()\nbefore_kernels()\n")
    res = json.loads(subprocess.run([*PYTHON, "-c", code], env=clean_environ(), capture_output=True,
                                    text=True, check=True).stdout)
    assert res["changed"] == ["NUMBA_CACHE_DIR", "NUMPY_MADVISE_HUGEPAGE", "OMP_WAIT_POLICY", "RIVERBED_OMP_DEFAULT"]
    assert res["numba"] == "riverbed_cli.runtime.numba_cache" and res["kept"] and res["freeze"] == 0 and res["gc"]
    # the user's own settings win
    user = {**clean_environ(), "OMP_WAIT_POLICY": "ACTIVE", "NUMPY_MADVISE_HUGEPAGE": "1", "GLIBC_TUNABLES": "",
            "NUMBA_CACHE_DIR": "/tmp/users-own"}
    res = json.loads(subprocess.run([*PYTHON, "-c", code], env=user, capture_output=True, text=True,
                                    check=True).stdout)
    assert res["changed"] == [] and not res["kept"]


def test_env_restores_the_variables_it_set(monkeypatch):
    for key in OURS:
        monkeypatch.delenv(key, raising=False)
    monkeypatch.setenv("NUMPY_MADVISE_HUGEPAGE", "1")  # the user's
    assert runtime.active() is None or runtime.active() is not None  # the session's Env may be active
    with Env() as env:
        assert runtime.active() is env
        assert os.environ["OMP_WAIT_POLICY"] == "PASSIVE" and os.environ["NUMPY_MADVISE_HUGEPAGE"] == "1"
        with Env() as inner:  # nested: nothing the outer one set changes
            assert runtime.active() is inner and inner._saved == {}
        assert runtime.active() is env
    assert "OMP_WAIT_POLICY" not in os.environ and "RIVERBED_OMP_DEFAULT" not in os.environ
    assert os.environ["NUMPY_MADVISE_HUGEPAGE"] == "1"


def test_outside_an_env_the_run_hooks_do_nothing(monkeypatch):
    monkeypatch.setattr(runtime, "_ACTIVE", [])
    assert not runtime.spin_between_regions() and not runtime.before_kernels()
    with runtime.prefault_heap(1 << 20) as nothing:
        assert nothing is None
    assert "GOMP_SPINCOUNT" not in os.environ or os.environ["GOMP_SPINCOUNT"] == os.environ.get("GOMP_SPINCOUNT")


# A kernel that inlines a helper of another module, run in a fresh process with NUMBA_CACHE_DIR as given
KERNEL = """
import sys
sys.path.insert(0, sys.argv[1])
from kern import kernel
print(kernel())
"""


def test_an_edited_helper_recompiles_the_kernels_that_inline_it(tmp_path):
    from riverbed_cli.runtime import numba_cache

    pkg = tmp_path / "pkg"
    pkg.mkdir()
    (pkg / "helper.py").write_text("from numba import njit\n\n\n@njit(inline='always')\ndef value():\n    return 1\n")
    (pkg / "kern.py").write_text("from numba import njit\nfrom helper import value\n\n\n@njit(cache=True)\n"
                                 "def kernel():\n    return value() + 10\n")

    def run(cache):
        env = {**os.environ, "NUMBA_CACHE_DIR": str(cache)}
        return subprocess.run([*PYTHON, "-c", KERNEL, str(pkg)], env=env, capture_output=True, text=True,
                              check=True).stdout.strip()

    first = numba_cache.cache_dir(pkg, root=tmp_path / "cache")
    assert run(first) == "11" and run(tmp_path / "fixed") == "11"
    (pkg / "helper.py").write_text((pkg / "helper.py").read_text().replace("return 1", "return 2"))
    # Numba's own key (the kernel's file) misses the helper's edit: the cached kernel still inlines the old helper
    assert run(tmp_path / "fixed") == "11"
    # a folder per sources' digest: a fresh cache, the edit compiled in; the old version's folder pruned
    second = numba_cache.cache_dir(pkg, root=tmp_path / "cache")
    assert second != first and run(second) == "12"
    assert numba_cache.prune_other_caches(second) == [first] and not first.exists() and second.exists()


def test_every_kernel_module_keys_the_cache(tmp_path):
    # a module whose kernels are @kernel (runtime/kernel.py) may name Numba nowhere: its edits must still recompile
    from riverbed_cli.runtime import numba_cache

    package = numba_cache.PACKAGE
    kernels = {p for p in package.rglob("*.py") if "@kernel" in p.read_text()}
    assert len(kernels) >= 30 and kernels <= set(numba_cache.kernel_sources())
    quiet = sorted(p for p in kernels if b"numba" not in p.read_bytes())
    assert quiet, "every kernel module names Numba: the rule for those that do not is untested"
    copy = tmp_path / package.name
    shutil.copytree(package, copy, ignore=shutil.ignore_patterns("__pycache__"))
    assert numba_cache.sources_digest(copy) == numba_cache.sources_digest(package)
    edited = copy / quiet[0].relative_to(package)
    edited.write_text(edited.read_text() + "\n# edited\n")
    assert numba_cache.sources_digest(copy) != numba_cache.sources_digest(package)
