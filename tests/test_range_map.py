"""``riverbed range-map``: per-pixel ranges from a disparity map (a previous run, or a coarser one) for
``riverbed match --range-map``."""

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from click.testing import CliRunner

from gates import inside_overlap
from riverbed_cli.cli.main import cli
from riverbed_cli.errors import RiverbedError
from riverbed_cli.io.disparity import read_disparity, write_disparity
from riverbed_cli.io.images import read_image
from riverbed_cli.io.windowed import read_range_map
from riverbed_cli.matching.tubes import ranges_from_disparity
from riverbed_cli.products.evaluate import evaluate_disparity

DATA = "tests/data/cones"


def test_ranges_from_disparity_hand_made_cases():
    disp = np.full((4, 6), np.nan, np.float32)
    disp[1, 1], disp[1, 2], disp[3, 5] = 10.0, 14.0, 30.0
    lo, hi = ranges_from_disparity(disp, window=1, margin=2.0)
    assert (lo[0, 0], hi[0, 0]) == (8.0, 12.0)  # the window holds 10 only
    assert (lo[1, 2], hi[1, 2]) == (8.0, 16.0)  # 10 and 14
    assert (lo[2, 4], hi[2, 4]) == (28.0, 32.0)  # 30
    assert np.isnan(lo[3, 0]) and np.isnan(hi[3, 0])  # nothing within one pixel: no range (the nominal one)
    # a map of the image downsampled by 2: coordinates halved, disparities doubled, the last row and column repeated
    lo, hi = ranges_from_disparity(disp, shape=(9, 13), window=0, margin=1.0)
    assert lo.shape == (9, 13)
    assert (lo[2, 2], hi[2, 2]) == (19.0, 21.0) and (lo[3, 5], hi[3, 5]) == (27.0, 29.0)
    assert (lo[8, 12], hi[8, 12]) == (59.0, 61.0) and np.isnan(lo[0, 0])
    with pytest.raises(RiverbedError, match="a 6x4 disparity map is not the 13x7 image downsampled by an integer"):
        ranges_from_disparity(disp, shape=(7, 13))


@pytest.fixture(scope="module")
def coarse_run(tmp_path_factory):
    """A previous run: unguided SGM of the Cones pair at half resolution (225 x 187, 0..31)."""
    tmp = tmp_path_factory.mktemp("range_map")
    for name in ("im2", "im6"):
        img = cv2.imread(f"{DATA}/{name}.png")
        cv2.imwrite(str(tmp / f"{name}_half.png"), cv2.resize(img, (225, 187), interpolation=cv2.INTER_AREA))
    r = CliRunner().invoke(cli, ["match", str(tmp / "im2_half.png"), str(tmp / "im6_half.png"), "--min-disp", "0",
                                 "--max-disp", "31", "-o", str(tmp / "coarse.tif")])
    assert r.exit_code == 0, r.output
    return tmp


def test_a_coarse_run_bounds_the_full_resolution_match(coarse_run, cones):
    tmp = coarse_run
    left, right, gt = cones
    # the window and margin the coarse match of the tube holes uses (docs/tubes.md)
    r = CliRunner().invoke(cli, ["range-map", str(tmp / "coarse.tif"), "--like", f"{DATA}/im2.png", "--window", "4",
                                 "--margin", "8", "--min-disp", "0", "--max-disp", "63", "-o", str(tmp / "ranges.tif"),
                                 "--json"])
    assert r.exit_code == 0, r.output
    info = json.loads(r.output)
    # the coarse run leaves its left edge, where a match may lie outside the right image, invalid: no range there
    # (the nominal one is searched)
    assert info["size"] == [450, 375] and info["factor"] == 2 and 0.94 < info["known_share"] < 0.96
    lo, hi = read_range_map(tmp / "ranges.tif")
    ev = np.isfinite(gt) & np.isfinite(lo)
    assert ((gt[ev] >= lo[ev]) & (gt[ev] <= hi[ev])).mean() > 0.98  # the coarse run's ranges hold the truth
    runs = {}
    for name, extra in (("full", []), ("ranges", ["--range-map", str(tmp / "ranges.tif")])):
        r = CliRunner().invoke(cli, ["match", f"{DATA}/im2.png", f"{DATA}/im6.png", "--min-disp", "0", "--max-disp",
                                     "63", *extra, "-o", str(tmp / f"{name}_d.tif"), "--json"])
        assert r.exit_code == 0, r.output
        runs[name] = json.loads(r.output), evaluate_disparity(read_disparity(tmp / f"{name}_d.tif"),
                                                              inside_overlap(gt))
    (full, e_full), (ranged, e_ranged) = runs["full"], runs["ranges"]
    assert full["range"] == "full" and ranged["range"] == "tube" and ranged["tubes"]["mean_width"] < 25  # of 64
    # unguided either way, searched near the coarse run's disparities only: as accurate over the GT pixels whose
    # match lies inside the right image (5.91 % / 0.695 px on the full range, 6.09 % / 0.718 px in the ranges)
    assert e_ranged["bad3"] <= e_full["bad3"] + 0.3 and e_ranged["avg"] <= e_full["avg"] * 1.05


def test_range_map_bad_inputs(coarse_run, tmp_path):
    tmp = coarse_run
    empty = tmp_path / "empty.tif"
    write_disparity(empty, np.full((20, 30), np.nan, np.float32))
    cases = [
        (["range-map", str(tmp / "coarse.tif"), "--like", f"{DATA}/im2.png", "-o", str(tmp_path / "r.png")],
         f"{tmp_path / 'r.png'}: range map must be written to a .tif file"),
        (["range-map", str(tmp / "coarse.tif"), "--like", str(tmp / "im2_half.png"), "--window", "1", "-o",
          str(tmp_path / "r.tif")], None),  # the same size: factor 1, fine
        (["range-map", str(empty), "-o", str(tmp_path / "e.tif")],
         f"{empty}: no valid disparity: the range map would be empty"),
        (["range-map", str(tmp / "coarse.tif"), "--min-disp", "9", "--max-disp", "3", "-o", str(tmp_path / "m.tif")],
         "--min-disp 9 is above --max-disp 3"),
    ]
    odd = tmp_path / "odd.png"
    cv2.imwrite(str(odd), cv2.resize(read_image(f"{DATA}/im2.png"), (449, 375)))
    cases.append((["range-map", str(tmp / "coarse.tif"), "--like", str(odd), "-o", str(tmp_path / "o.tif")],
                  f"{tmp / 'coarse.tif'}: a 225x187 disparity map is not the 449x375 image downsampled by an "
                  "integer factor"))
    for args, message in cases:
        r = CliRunner().invoke(cli, args)
        out = args[args.index("-o") + 1]
        if message is None:
            assert r.exit_code == 0, r.output
            continue
        assert r.exit_code == 1 and r.output == f"riverbed: error: {message}\n", (args, r.output)
        assert not Path(out).exists()
    # an existing output is kept without --overwrite
    r = CliRunner().invoke(cli, ["range-map", str(tmp / "coarse.tif"), "-o", str(tmp_path / "r.tif")])
    assert r.exit_code == 1 and "output exists; pass --overwrite" in r.output
