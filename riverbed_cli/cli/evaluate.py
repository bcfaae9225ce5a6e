"""``riverbed evaluate``: compare a disparity map with ground truth."""

import math

import click

from ..errors import RiverbedError
from ..io.atomic import check_output
from ..io.disparity import read_disparity
from ..products.dsm_compare import compare_dsm, read_dsm_on_grid
from ..products.evaluate import evaluate_disparity, evaluation_mask
from ..products.visualize import difference_picture, error_map_picture, write_picture
from .options import input_path, json_opt, overwrite_opt, print_json

# name -> (unit, what it is) for the text table
_ROWS = {
    "bad1": ("%", "error > 1 px or no prediction"),
    "bad2": ("%", "error > 2 px or no prediction"),
    "bad3": ("%", "error > 3 px or no prediction"),
    "avg": ("px", "mean absolute error of the predicted pixels"),
    "rmse": ("px", "root mean square error of the predicted pixels"),
    "density": ("%", "pixels with a prediction"),
    "d1": ("%", "KITTI D1: error > 3 px and > 5 %, or no prediction"),
    "n": ("px", "ground-truth pixels evaluated"),
}


@click.command("evaluate")
@click.argument("disp", type=input_path())
@click.argument("gt", type=input_path())
@click.option("--dsm", "dsm_mode", is_flag=True,
              help="Compare two DSM GeoTIFFs instead (DISP is the DSM, GT the reference DSM).")
@click.option("--thresholds", default="0.5,1,2", show_default=True,
              help="With --dsm: |dz| thresholds (height units) for the shares of large differences.")
@click.option("--exclude", type=input_path(), default=None,
              help="Sparse disparity map (e.g. the LiDAR guidance) whose valid pixels are left out.")
@click.option("--max-disp", type=float, default=None,
              help="Leave out ground truth above this disparity (px).")
@click.option("--gt-scale", type=float, default=None,
              help="GT stored value per pixel of disparity, d = value / S. Needed for 8-bit PNG (4 for "
                   "Middlebury quarter size, 2 for half size); default 256 for 16-bit PNG, 1 for PFM/TIFF.")
@click.option("--disp-scale", type=float, default=None, help="Same as --gt-scale, for DISP.")
@json_opt
@click.option("--error-map", "error_png", type=click.Path(dir_okay=False), default=None,
              help="Write a colour error map PNG (blue small ... red large, magenta no prediction, "
                   "black no GT).")
@overwrite_opt
def evaluate_cmd(disp, gt, dsm_mode, thresholds, exclude, max_disp, gt_scale, disp_scale, as_json, error_png,
                 overwrite):
    """Compare disparity map DISP with ground truth GT (.pfm, .png or .tif).

    The metrics are taken over the GT pixels, minus the --exclude pixels and GT above --max-disp, with
    e = |DISP - GT| in pixels:

    \b
      bad1, bad2, bad3  % with e > 1, 2, 3 px or no prediction
      avg               mean e over the pixels with a prediction (px)
      rmse              root mean square e over the same pixels (px)
      density           % with a prediction
      d1                KITTI D1: % with e > 3 px and e > 5 % of GT, or no prediction
      n                 number of pixels evaluated

    With --dsm, DISP and GT are DSMs (GeoTIFF) compared on GT's grid (DISP is reprojected with rasterio when the
    grids differ): mean, median, rmse, nmad and std of dz = DSM - REF, the % of cells with |dz| above each threshold
    and above 3 cell sizes, completeness (% of REF cells the DSM covers) and n; --error-map writes the dz map.
    """
    if error_png is not None:
        # Refuse before the work, not after it.
        if not error_png.lower().endswith(".png"):
            raise RiverbedError("error map must be a .png file", error_png)
        check_output(error_png, overwrite, inputs=[disp, gt, exclude])
    if dsm_mode:
        return _evaluate_dsm(disp, gt, thresholds, as_json, error_png, overwrite)

    d = read_disparity(disp, scale=disp_scale)
    g = read_disparity(gt, scale=gt_scale)
    if d.shape != g.shape:
        raise RiverbedError(
            f"ground truth is {g.shape[0]}x{g.shape[1]} but disparity {disp} is {d.shape[0]}x{d.shape[1]}", gt
        )
    ex = None
    if exclude is not None:
        # Only which pixels are valid matters, so any scale will do (and 8-bit PNG needs one).
        ex = read_disparity(exclude, scale=1.0)
        if ex.shape != g.shape:
            raise RiverbedError(
                f"exclusion map is {ex.shape[0]}x{ex.shape[1]} but ground truth {gt} is "
                f"{g.shape[0]}x{g.shape[1]}",
                exclude,
            )

    metrics = evaluate_disparity(d, g, exclude=ex, max_disp=max_disp)

    if error_png is not None:
        write_picture(error_png, error_map_picture(d, g, evaluation_mask(g, ex, max_disp), metrics),
                      overwrite=overwrite)

    if as_json:
        # JSON has no NaN: a metric without any valid prediction is null.
        print_json({k: (None if isinstance(v, float) and math.isnan(v) else v) for k, v in metrics.items()})
    else:
        for name, value in metrics.items():
            unit, what = _ROWS[name]
            shown = f"{value:d}" if name == "n" else ("n/a" if math.isnan(value) else f"{value:.3f}")
            click.echo(f"{name:<8}{shown:>12} {unit:<3} {what}")


def _evaluate_dsm(dsm_path, ref_path, thresholds, as_json, error_png, overwrite):
    try:
        ts = tuple(float(t) for t in thresholds.split(",") if t.strip())
    except ValueError:
        raise RiverbedError(f"--thresholds '{thresholds}' is not a comma-separated list of numbers") from None
    if not ts or not all(math.isfinite(t) and t > 0 for t in ts):
        raise RiverbedError(f"--thresholds '{thresholds}': each threshold must be a finite number > 0")
    dsm, ref, res = read_dsm_on_grid(dsm_path, ref_path)
    metrics = compare_dsm(dsm, ref, ts, resolution=res)
    if error_png is not None:
        write_picture(error_png, difference_picture(dsm, ref, metrics), overwrite=overwrite)
    if as_json:
        print_json({k: (None if isinstance(v, float) and math.isnan(v) else v) for k, v in metrics.items()})
    else:
        for name, value in metrics.items():
            unit = "" if name == "n" else ("%" if name.startswith("over") or name == "completeness" else "m")
            shown = f"{value:d}" if name == "n" else ("n/a" if math.isnan(value) else f"{value:.3f}")
            click.echo(f"{name:<13}{shown:>12} {unit}")
