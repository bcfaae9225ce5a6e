import json
import os
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
from click.testing import CliRunner

from riverbed_cli.cli.main import cli
from riverbed_cli.io.disparity import read_disparity, read_disparity_tags, write_disparity
from riverbed_cli.products.evaluate import evaluate_disparity
from riverbed_cli.products.simulate import simulate_lidar
from riverbed_cli.products.visualize import disparity_picture
from conftest import PYTHON

DATA = Path(__file__).parent / "data" / "cones"
LEFT, RIGHT, GT = str(DATA / "im2.png"), str(DATA / "im6.png"), str(DATA / "disp2.png")


@pytest.fixture()
def work(tmp_path, cones):
    gt = cones[2]
    write_disparity(tmp_path / "sparse.tif", simulate_lidar(gt, 0.05, seed=0))
    write_disparity(tmp_path / "small.tif", simulate_lidar(gt, 0.05, seed=0)[:100])
    write_disparity(tmp_path / "empty.tif", np.full(gt.shape, np.nan, np.float32))
    cv2.imwrite(str(tmp_path / "right_small.png"), cv2.imread(RIGHT)[:, :400])
    (tmp_path / "broken.png").write_bytes(b"not a png")
    return tmp_path


def run(args):
    return CliRunner().invoke(cli, args)


def test_match_guided_json_and_accuracy(work):
    out = work / "d.tif"
    r = run(["match", LEFT, RIGHT, "--sparse", str(work / "sparse.tif"), "-o", str(out), "--json",
             "--color", str(work / "d.png")])
    assert r.exit_code == 0, r.output
    s = json.loads(r.output)
    assert s["guide"] == "riverbed" and s["window"] == 9
    assert set(s["stages"]) == {"lidar_offset", "lidar_check", "range", "cost", "guidance", "aggregation", "refinement",
                                "fusion"}
    assert s["fusion"] == "confidence" and set(s["fusion_stats"]) == {"stereo_sigma", "agree", "lidar", "stereo", "invalid",
                                                                      "mean_confidence"}
    assert s["range"] == "tube" and s["tubes"]["nominal"] == s["d_max"] - s["d_min"] + 1
    assert 0 < s["seconds"] and abs(s["lidar_share"] - 0.05) < 0.002
    assert s["d_min"] <= 9 and s["d_max"] >= 55  # derived from the sparse map (9.25 .. 55) with a margin
    gt = read_disparity(GT, scale=4)
    m = evaluate_disparity(read_disparity(out), gt, exclude=read_disparity(work / "sparse.tif"))
    assert m["bad3"] < 2.5 and m["avg"] < 0.4
    assert read_disparity_tags(out)["riverbed_guide"] == "riverbed"
    # The colour preview: the Turbo map at 1:1 (under a title, beside its colour bar), exactly.
    preview = disparity_picture(read_disparity(out))
    assert preview.data.shape == (375, 450, 3)
    np.testing.assert_array_equal(cv2.cvtColor(cv2.imread(str(work / "d.png")), cv2.COLOR_BGR2RGB), preview.rgb)


@pytest.mark.parametrize("ext", [".pfm", ".png"])
def test_match_unguided_other_formats(work, ext):
    out = work / f"d{ext}"
    r = run(["match", LEFT, RIGHT, "--max-disp", "59", "--paths", "4", "--census", "5x5", "--no-subpixel",
             "--lr-check", "--median", "1", "-o", str(out)])
    assert r.exit_code == 0, r.output
    d = read_disparity(out)
    assert d.shape == (375, 450)
    assert 0.7 < np.isfinite(d).mean() < 0.99  # the left-right check removed occlusions and mismatches
    v = d[np.isfinite(d)]
    assert np.allclose(v, np.round(v))  # no sub-pixel


CASES = {
    "missing": (["nope.png", RIGHT, "--max-disp", "60"], "nope.png: file not found"),
    "size": ([LEFT, "{w}/right_small.png", "--max-disp", "60"],
             "{w}/right_small.png: left and right images differ in size: 375x450 vs 375x400 (height x width; "
             f"left image {LEFT})"),
    "unreadable": ([LEFT, "{w}/broken.png", "--max-disp", "60"],
                   "{w}/broken.png: cannot read image (not a format OpenCV or rasterio reads)"),
    "sparse shape": ([LEFT, RIGHT, "--sparse", "{w}/small.tif"],
                     "{w}/small.tif: sparse map is 450x100 but the images are 450x375 (WxH)"),
    "range": ([LEFT, RIGHT, "--sparse", "{w}/sparse.tif", "--min-disp", "70", "--max-disp", "90"],
              "{w}/sparse.tif: disparity range [70, 90] excludes all sparse disparities (they span [9.25, 55.00])"),
    "empty": ([LEFT, RIGHT, "--sparse", "{w}/empty.tif"], "{w}/empty.tif: sparse map has no valid disparities"),
    "no range": ([LEFT, RIGHT], "give --max-disp (and --min-disp), --pair (the pair file riverbed rectify wrote), "
                                    "or --sparse or --range-map to derive the disparity range from"),
    "format": ([LEFT, RIGHT, "--max-disp", "50", "-o", "{w}/d.xyz"],
               "{w}/d.xyz: unsupported disparity format '.xyz' (use .pfm, .png or .tif)"),
    "guide": ([LEFT, RIGHT, "--max-disp", "50", "--guide", "gauss"], "--guide gauss needs --sparse"),
}


@pytest.mark.parametrize("case", CASES)
def test_bad_input_one_line_error_and_no_output(work, case):
    args, msg = CASES[case]
    args = [a.format(w=work) for a in args]
    out = work / "out.tif"
    if "-o" not in args:
        args += ["-o", str(out)]
    r = run(["match", *args])
    assert r.exit_code == 1
    assert r.output == f"riverbed: error: {msg.format(w=work)}\n"
    assert not out.exists() and not (work / "d.xyz").exists()
    assert not list(work.glob(".*tmp*"))


def test_existing_output_is_kept_without_overwrite(work):
    out = work / "d.tif"
    out.write_bytes(b"precious")
    r = run(["match", LEFT, RIGHT, "--max-disp", "59", "-o", str(out)])
    assert r.exit_code == 1 and r.output == f"riverbed: error: {out}: output exists; pass --overwrite to replace it\n"
    assert out.read_bytes() == b"precious"
    assert run(["match", LEFT, RIGHT, "--max-disp", "59", "-o", str(out), "--overwrite"]).exit_code == 0
    assert read_disparity(out).shape == (375, 450)


def test_installed_command_runs_the_pair(work):
    exe = Path(sys.executable).parent / "riverbed"
    assert exe.exists(), "the riverbed console script is not installed next to this Python"
    out = work / "cmd.tif"
    p = subprocess.run([str(exe), "match", LEFT, RIGHT, "--sparse", str(work / "sparse.tif"), "-o", str(out),
                        "--json"], capture_output=True, text=True, timeout=600)
    assert p.returncode == 0, p.stderr
    assert json.loads(p.stdout)["output"] == str(out)
    assert p.stderr == ""  # quiet in a pipe: no progress bar, no log lines
    p = subprocess.run([str(exe), "match", "nope.png", RIGHT, "--max-disp", "9", "-o", str(work / "x.tif")],
                       capture_output=True, text=True, timeout=600)
    assert p.returncode == 1 and p.stderr == "riverbed: error: nope.png: file not found\n"


def test_16_bit_and_grey_inputs_match_like_8_bit(work):
    grey = [cv2.imread(p, cv2.IMREAD_GRAYSCALE) for p in (LEFT, RIGHT)]
    for name, img in zip(("l8.png", "r8.png"), grey):
        cv2.imwrite(str(work / name), img)
    for name, img in zip(("l16.tif", "r16.tif"), grey):
        cv2.imwrite(str(work / name), img.astype(np.uint16) * 257)  # full 16-bit range, same ordering
    for a, b, out in (("l8.png", "r8.png", "d8.tif"), ("l16.tif", "r16.tif", "d16.tif")):
        r = run(["match", str(work / a), str(work / b), "--max-disp", "59", "-o", str(work / out)])
        assert r.exit_code == 0, r.output
    np.testing.assert_array_equal(read_disparity(work / "d8.tif"), read_disparity(work / "d16.tif"))


_HUGEPAGE_PROBE = (
    "from riverbed_cli.runtime import Env\n"
    "Env().__enter__()\n"
    "import numpy\n"
    "try:\n    from numpy._core.multiarray import _set_madvise_hugepage\n"
    "except ImportError:\n    from numpy.core.multiarray import _set_madvise_hugepage\n"
    "print(_set_madvise_hugepage(True))"
)


@pytest.mark.parametrize("user, expected", [(None, "False"), ("1", "True")])
def test_command_line_turns_numpy_huge_pages_off_unless_the_user_set_them(user, expected):
    # first-touching the cost volumes in huge pages is slower on THP-madvise hosts (riverbed_cli/runtime/heap.py, set
    # by its Env before NumPy is imported); the user's own NUMPY_MADVISE_HUGEPAGE wins
    env = {k: v for k, v in os.environ.items() if k != "NUMPY_MADVISE_HUGEPAGE"}
    if user is not None:
        env["NUMPY_MADVISE_HUGEPAGE"] = user
    out = subprocess.run([*PYTHON, "-c", _HUGEPAGE_PROBE], env=env, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == expected


_MALLOC_PROBE = (
    "from riverbed_cli.runtime import Env\n"
    "Env().__enter__()\n"
    "import numpy as np, os\n"
    "def rss():\n    return int(open('/proc/self/statm').read().split()[1]) * os.sysconf('SC_PAGE_SIZE') >> 20\n"
    "a = np.ones(64 << 17)\nbefore = rss()\ndel a\nprint(before - rss() < 16)"  # 64 MiB freed: still resident?
)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's malloc and /proc")
@pytest.mark.parametrize("user, kept", [({}, "True"), ({"GLIBC_TUNABLES": ""}, "False"),
                                        ({"MALLOC_TRIM_THRESHOLD_": "65536"}, "False")])
def test_command_line_keeps_freed_memory_unless_the_user_set_malloc(user, kept):
    # riverbed_cli/runtime/heap.py: glibc keeps a freed 64 MiB array for the next stage (fewer page faults) instead
    # of returning it to the kernel; a user's own malloc settings win
    env = {k: v for k, v in os.environ.items() if k not in ("MALLOC_MMAP_THRESHOLD_", "MALLOC_TRIM_THRESHOLD_",
                                                             "GLIBC_TUNABLES")}
    out = subprocess.run([*PYTHON, "-c", _MALLOC_PROBE], env={**env, **user}, capture_output=True, text=True,
                         check=True)
    assert out.stdout.strip() == kept


_FRESH_MATCH = (
    "import hashlib, sys\n"
    "from riverbed_cli.__main__ import main\n"
    "a = sys.argv[1:]\n"
    "try:\n    main(['match', a[0], a[1], '--sparse', a[2], '-o', a[3], '--overwrite'])\n"
    "except SystemExit as e:\n    assert not e.code, e.code\n"
    "from riverbed_cli.io.disparity import read_disparity\n"
    "print('numba.np.arraymath' in sys.modules, 'scipy.linalg' in sys.modules,"
    " hashlib.sha256(read_disparity(a[3]).tobytes()).hexdigest())"
)


@pytest.mark.parametrize("refresh", [None, "1"])
def test_command_line_loads_cached_kernels_without_numbas_compiler_start_up(work, refresh):
    # riverbed_cli/runtime/numba_cache.py: a fresh `riverbed match` loads its cached kernels without Numba's target
    # context refresh (which imports numba.np.arraymath and, through it, scipy.linalg) and matches the same bits;
    # RIVERBED_NUMBA_REFRESH=1 keeps Numba's own behaviour
    env = {k: v for k, v in os.environ.items() if k != "RIVERBED_NUMBA_REFRESH"}
    if refresh is not None:
        env["RIVERBED_NUMBA_REFRESH"] = refresh
    args = [LEFT, RIGHT, str(work / "sparse.tif"), str(work / "d.tif")]
    subprocess.run([*PYTHON, "-c", _FRESH_MATCH, *args], env=env, check=True, capture_output=True)  # cache
    out = subprocess.run([*PYTHON, "-c", _FRESH_MATCH, *args], env=env, capture_output=True, text=True,
                         check=True).stdout.split()
    assert out[:2] == (["True", "True"] if refresh else ["False", "False"])
    same = subprocess.run([*PYTHON, "-c", _FRESH_MATCH, *args],
                          env={**env, "RIVERBED_NUMBA_REFRESH": "0" if refresh else "1"}, capture_output=True,
                          text=True, check=True).stdout.split()
    assert same[2] == out[2]


def test_progress_bar_draws_on_a_terminal_only(monkeypatch):
    import io

    from riverbed_cli.cli import options

    err = io.StringIO()
    monkeypatch.setattr(sys, "stderr", err)  # a pipe: nothing drawn, tqdm not needed
    with options.progress_bar(4, desc="match") as bar:
        bar.update(4)
    assert err.getvalue() == "" and type(bar).__name__ == "_NoBar"
    err.isatty = lambda: True  # a terminal: tqdm draws its bar on stderr
    with options.progress_bar(4, desc="match") as bar:
        bar.update(4)
    assert type(bar).__name__ == "tqdm" and "match: 100%" in err.getvalue()
    with options.progress_bar(4, enabled=False, desc="dsm") as bar:  # nothing to count: no bar either
        bar.update(4)
    assert "dsm" not in err.getvalue()
