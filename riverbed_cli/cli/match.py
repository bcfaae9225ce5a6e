"""``riverbed match``: dense disparity of a rectified pair, optionally guided by sparse LiDAR disparities.

Every matching setting is an option generated from the settings table (:data:`~riverbed_cli.matching.config.
MATCH_SETTINGS`), so ``riverbed match`` and a block manifest take the same names, values and messages. This
module loads no Numba kernel: the matching library is imported when the command runs.
"""

import logging
import math
import os

import click

from ..errors import RiverbedError
from ..matching.config import MATCH_SETTINGS, MatchConfig
from .options import input_path, json_opt, output_opt, overwrite_opt, print_json, progress_bar, setting_options

_MATCH = [s for s in MATCH_SETTINGS if s.group is not None]
_RUN = [s for s in MATCH_SETTINGS if s.group is None and s.name not in ("tile", "overlap", "lidar_range")]

log = logging.getLogger(__name__)


def pair_range(path, left):
    """The disparity range ``(lo, hi)`` (whole px, widened to them) a pair file states (``riverbed rectify``'s
    tie-point range, or an RPC pair's over its heights); one line naming the file when it states none. Warns
    when the pair file names another left image than ``left``."""
    from ..geometry.pairfile import load_pairfile  # the geometry stack (scipy) loads only for --pair

    pair = load_pairfile(path, accept_rpc=True)
    if pair.left is not None and os.path.abspath(left) != os.path.abspath(pair.left):
        log.warning("%s: its left image is %s, not %s", path, pair.left, left)
    if pair.disparity is None:
        raise RiverbedError("no disparity range in the pair file (riverbed rectify writes one when it finds tie "
                            "points); give --min-disp/--max-disp, --sparse or --range-map", path)
    lo, hi = pair.disparity
    return int(math.floor(lo)), int(math.ceil(hi))


@click.command("match")
@click.argument("left", type=input_path())
@click.argument("right", type=input_path())
@output_opt
@click.option("--sparse", type=input_path(), default=None,
              help="Sparse LiDAR disparities of the left image (.tif/.pfm/.png; NaN, inf or 0 = none).")
@click.option("--sparse-scale", type=float, default=None, help="Stored value per pixel for an 8-bit PNG --sparse.")
@click.option("--pair", "pair_file", type=input_path(), default=None,
              help="The pair file riverbed rectify wrote: its disparity range is searched where --min-disp/--max-disp "
                   "are not given (also with --sparse).")
@click.option("--range-map", type=input_path(), default=None,
              help="Per-pixel search range from elsewhere (a coarse DSM, a previous run): a 2-band TIFF of min and "
                   "max disparity (NaN: the nominal range); searched as tubes instead of the LiDAR's.")
@setting_options(_MATCH, defaults={"guide": None})
@setting_options(_RUN)
@click.option("--color", "color_png", type=click.Path(dir_okay=False), default=None,
              help="Also write a colourised disparity preview PNG.")
@click.option("--confidence", "confidence", type=click.Path(dir_okay=False), default=None,
              help="Also write the fusion's per-pixel confidence (.tif, float32 in [0, 1]: the estimated "
                   "probability that the disparity is within 1 px of the truth; tiled: each tile's own fusion; "
                   "docs/fusion.md).")
@click.option("--lidar-mask", "lidar_mask", type=click.Path(dir_okay=False), default=None,
              help="Also write what the LiDAR did per pixel (.png, uint8): 0 no LiDAR, 1 a point used, 2 a point "
                   "dropped as an outlier, 3 a point dropped in a changed region, 4 a pixel of a changed area "
                   "(--lidar-check; docs/lidar_faults.md).")
@click.option("--tile", default="auto", show_default=True,
              help="Tile side (px) for large images, 'auto' (untiled when the whole range fits the memory budget, "
                   "else tiles sized for the widest LiDAR range; the rule blocks use) or 0 (never tile). Tiles of "
                   "TIFF inputs are read by windows.")
@click.option("--overlap", type=int, default=128, show_default=True, help="Tile overlap (px).")
@click.option("--lidar-range/--global-range", default=True, show_default=True,
              help="With tiles and --sparse: each tile searches only the disparities its LiDAR allows.")
@json_opt
@overwrite_opt
def match_cmd(left, right, output, pair_file, sparse, sparse_scale, range_map, color_png, confidence, lidar_mask, tile,
              overlap, lidar_range, as_json, overwrite, **settings):
    """Match rectified images LEFT (reference) and RIGHT into a disparity map OUTPUT.

    Disparity d = x_left - x_right (px). OUTPUT format by extension: .tif (float32, NaN invalid), .pfm
    (Middlebury, inf invalid) or .png (KITTI 16-bit, d*256, 0 invalid). Options marked [name] apply to that
    matcher or guide only.
    """
    from ..scale.match_files import match_files  # the matching stack loads here, not for --help

    if settings["guide"] is None:
        settings["guide"] = "riverbed" if sparse else "none"
    run = {s.name: settings.pop(s.name) for s in _RUN}
    if pair_file is not None:
        lo, hi = pair_range(pair_file, left)
        run["min_disp"] = lo if run["min_disp"] is None else run["min_disp"]
        run["max_disp"] = hi if run["max_disp"] is None else run["max_disp"]
    config = MatchConfig.from_settings(settings)
    bars = []

    def progress(total):
        bars.append(progress_bar(total, desc="match", leave=False))
        return bars[-1].update

    try:
        summary = match_files(left, right, output, config, sparse=sparse, sparse_scale=sparse_scale,
                              min_disp=run["min_disp"], max_disp=run["max_disp"], max_pixels=run["max_pixels"],
                              tile=tile, overlap=overlap, lidar_range=lidar_range, color_png=color_png,
                              confidence=confidence, overwrite=overwrite, progress=progress, range_map=range_map,
                              lidar_mask=lidar_mask)
    finally:
        for bar in bars:
            bar.close()
    if as_json:
        print_json(summary)
