"""``riverbed pair``: a pair file from a benchmark calibration (Middlebury 2014 ``calib.txt``, KITTI)."""

import logging
from pathlib import Path

import click

from ..errors import RiverbedError
from ..geometry.cameras import kitti_pair, middlebury_pair
from ..io.atomic import check_output
from ..io.images import read_image
from ..geometry.pairfile import pair_to_dict, write_pairfile
from .options import input_path, json_opt, output_opt, overwrite_opt, print_json

log = logging.getLogger(__name__)


def _check_pair_output(output, overwrite, inputs=()):
    if Path(output).suffix.lower() not in (".yaml", ".yml", ".json"):
        raise RiverbedError("pair file must end in .yaml, .yml or .json", output)
    check_output(output, overwrite, inputs)


def _report(output, pair, as_json):
    if as_json:
        print_json({"output": str(output), "baseline": pair.baseline, "focal": pair.focal,
                    "exactly_rectified": pair.exactly_rectified, **pair_to_dict(pair, Path(output).parent)})
    else:
        log.info("%s: f = %.4f px, baseline %.6g", output, pair.focal, pair.baseline)


@click.group("pair")
def pair_cmd():
    """Write a pair file (the geometry of a rectified pair) from a benchmark calibration."""


@pair_cmd.command("middlebury")
@click.argument("calib", type=input_path())
@output_opt
@click.option("--left", type=click.Path(dir_okay=False), default=None,
              help="Left image (default: im0.png beside CALIB).")
@click.option("--right", type=click.Path(dir_okay=False), default=None,
              help="Right image (default: im1.png beside CALIB).")
@click.option("--scale", type=float, default=1.0, show_default=True,
              help="Image size factor for reduced images (0.5 half, 0.25 quarter): scales f, cx, cy, doffs, "
                   "size.")
@json_opt
@overwrite_opt
def middlebury_cmd(calib, output, left, right, scale, as_json, overwrite):
    """Pair file OUTPUT (.yaml/.json) from a Middlebury 2014 CALIB (calib.txt: cam0, cam1, doffs, baseline).

    The left camera frame is the world, in metres (the file's baseline is in mm).
    """
    _check_pair_output(output, overwrite, [calib, left, right])
    folder = Path(calib).parent
    pair = middlebury_pair(calib, scale=scale, left=Path(left or folder / "im0.png").absolute(),
                           right=Path(right or folder / "im1.png").absolute())
    write_pairfile(output, pair, overwrite=overwrite,
                   comment=f"riverbed pair file from Middlebury {calib} (scale {scale:g}); world = left "
                           "camera, m")
    _report(output, pair, as_json)


@pair_cmd.command("kitti")
@click.argument("calib", type=input_path())
@output_opt
@click.option("--left", type=click.Path(dir_okay=False), default=None,
              help="Left image (image_2); its size is stored in the pair file.")
@click.option("--right", type=click.Path(dir_okay=False), default=None, help="Right image (image_3).")
@json_opt
@overwrite_opt
def kitti_cmd(calib, output, left, right, as_json, overwrite):
    """Pair file OUTPUT (.yaml/.json) from a KITTI object CALIB (P2, P3, R0_rect, Tr_velo_to_cam).

    P_left/P_right are P2/P3; the registration R0_rect @ Tr_velo_to_cam maps Velodyne points to the rectified
    camera-0 frame, which is the world (metres).
    """
    _check_pair_output(output, overwrite, [calib, left, right])
    size = {}
    if left:
        h, w = read_image(left).shape[:2]
        size = {"width": w, "height": h}
    pair = kitti_pair(calib, left=Path(left).absolute() if left else None,
                      right=Path(right).absolute() if right else None, **size)
    write_pairfile(output, pair, overwrite=overwrite,
                   comment=f"riverbed pair file from KITTI {calib}; world = rectified camera 0, m")
    _report(output, pair, as_json)
