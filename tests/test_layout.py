"""The package's architecture, held by tests: layering, public names across modules, imports at module top, a
``riverbed --help`` that loads no Numba kernel, and registries that agree with the settings table."""

import re
import subprocess
from pathlib import Path

from layout_check import summary

from riverbed_cli.matching import pipeline  # noqa: F401  (fills the registries)
from riverbed_cli.matching.config import GUIDE_NAMES, MATCH_SETTINGS, MATCHER_NAMES, MatchConfig
from riverbed_cli.matching.registry import GUIDES, MATCHERS
from conftest import PYTHON

PACKAGE = Path(__file__).resolve().parents[1] / "riverbed_cli"

#: Function-level imports that are there on purpose (not to dodge a cycle), with the reason.
ALLOWED_LOCAL_IMPORTS = {
    "riverbed_cli.cli.match": "the matching stack loads when the command runs, so `riverbed match --help` stays fast",
    "riverbed_cli.scale.block.runner": "dask.distributed is an optional dependency (the dask extra)",
    "riverbed_cli.products.visualize": "matplotlib loads only when a picture is drawn: commands writing none skip it",
    "riverbed_cli.geometry.rpc": "shareloc (numba, 1.3 s) loads only to read OSSIM .geom and DIMAP v1 RPC files",
    "riverbed_cli.runtime.numba_cache": "Numba loads when a command runs, not for `riverbed match --help`",
    "riverbed_cli.runtime.threads": "Numba and OpenCV load when a command runs with --threads, not for --help",
    "riverbed_cli.__main__": "the program's Env is entered before NumPy is imported (it reads its settings then)",
    "riverbed_cli.cli.options": "tqdm (22-34 ms after Numba) loads only for a progress bar that shows on a terminal",
    # the AD-Census, riverbed+ and diffusion kernels' modules load only in the runs that use them: a default
    # `riverbed match` starts 0.03-0.05 s sooner (docs/tubes.md, start-up)
    "riverbed_cli.matching.matchers.adcensus": "AD-Census's modules load when the AD-Census matcher runs",
    "riverbed_cli.matching.guides.riverbed": "riverbed+ (and AD-Census) load when a support map is asked for",
    "riverbed_cli.matching.guides.riverbed_plus": "riverbed+ (and AD-Census) load when the riverbed+ guide runs",
    "riverbed_cli.matching.guides.diffusion": "the diffusion kernels load when the diffusion guide runs",
}


def test_no_module_imports_from_a_higher_layer():
    assert summary(PACKAGE)["higher_layer_imports"] == []


def test_no_private_name_is_imported_from_another_module():
    assert summary(PACKAGE)["private_imports"] == []


def test_imports_sit_at_module_top():
    local = [loc for loc in summary(PACKAGE)["function_level_imports"] if loc.split(":")[0] not in
             ALLOWED_LOCAL_IMPORTS]
    assert local == []


def test_no_module_over_600_lines():
    assert summary(PACKAGE)["over_600_lines"] == []


def _imported_by(code):
    out = subprocess.run([*PYTHON, "-c", code + "\nimport sys\nprint('\\n'.join(sorted(sys.modules)))"],
                         capture_output=True, text=True, check=True).stdout.split()
    return [m for m in out if m.startswith(("numba", "riverbed_cli.matching.census", "riverbed_cli.matching.sgm"))]


def test_help_loads_no_numba_kernel():
    run = "from riverbed_cli.cli.main import cli\ntry:\n    cli([{args}])\nexcept SystemExit:\n    pass"
    assert _imported_by(run.format(args="'--help'")) == []
    assert _imported_by(run.format(args="'match', '--help'")) == []
    assert _imported_by("import riverbed_cli") == []


def test_registries_are_full_on_first_access():
    # no module imported the plugins (nor matching.pipeline): reading the tables loads them
    code = ("import sys, riverbed_cli\nfrom riverbed_cli.matching.registry import FUSIONS\n"
            "print(sorted(riverbed_cli.MATCHERS), sorted(riverbed_cli.GUIDES), sorted(FUSIONS),"
            " 'riverbed_cli.matching.pipeline' in sys.modules)")
    out = subprocess.run([*PYTHON, "-c", code], capture_output=True, text=True, check=True).stdout.strip()
    assert out == str(sorted(MATCHER_NAMES)) + " " + str(sorted(GUIDE_NAMES)) + " ['confidence', 'none'] False"


def test_registries_agree_with_the_settings_table():
    assert set(MATCHERS) == set(MATCHER_NAMES)
    assert set(GUIDES) == set(GUIDE_NAMES)
    assert {s.name for s in MATCH_SETTINGS if s.group is not None} == set(MatchConfig().to_settings())
    names = [s.name for s in MATCH_SETTINGS]
    assert len(names) == len(set(names))


def test_every_kernel_has_the_one_decorator():
    # runtime/kernel.py's @kernel is the only way into Numba's njit: the options (cache, inline, parallel) in one place
    found = [f"{p.relative_to(PACKAGE)}:{i}" for p in sorted(PACKAGE.rglob("*.py")) if p.name != "kernel.py"
             for i, line in enumerate(p.read_text().splitlines(), 1) if re.search(r"\bnjit\b|\bjit\(", line)]
    assert found == []
    assert sum(p.read_text().count("@kernel") for p in PACKAGE.rglob("*.py")) >= 160
