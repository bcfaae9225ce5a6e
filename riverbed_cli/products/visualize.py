"""Pictures of disparity maps: colourised disparity and error maps (RGB ``uint8``), and a PNG writer.

Conventions: arrays ``H x W`` indexed ``[row, col]``, disparity ``d = x_left - x_right`` in pixels, NaN
invalid; colour images are ``H x W x 3`` in RGB order.
"""

from pathlib import Path

import cv2
import numpy as np

from ..errors import RiverbedError
from ..io.atomic import atomic_output
from ..io.images import write_png_file

#: Colour bins of the absolute error, in pixels: ``(upper bound, RGB)``; the colours are the KITTI devkit's
#: (blue for small errors ... red for large), the bounds double from 1/16 px to 16 px.
ERROR_BINS = (
    (0.0625, (49, 54, 149)),
    (0.125, (69, 117, 180)),
    (0.25, (116, 173, 209)),
    (0.5, (171, 217, 233)),
    (1.0, (224, 243, 248)),
    (2.0, (254, 224, 144)),
    (4.0, (253, 174, 97)),
    (8.0, (244, 109, 67)),
    (16.0, (215, 48, 39)),
    (np.inf, (165, 0, 38)),
)
#: Colour of ground-truth pixels without a (valid) prediction.
MISSING_COLOUR = (255, 0, 255)


def colorize_disparity(disp, vmin=None, vmax=None):
    """Colourise a disparity map with the Turbo colour map.

    Parameters
    ----------
    disp : array_like, ``H x W``
        Disparity in pixels; NaN (any non-finite value) is invalid.
    vmin, vmax : float, optional
        Disparities mapped to the two ends of the colour map; values outside are clipped. Default: the minimum
        and maximum of the finite values. Min/max rather than percentiles because a matcher's disparities are
        already bounded by its search range; pass the ground truth's range to compare maps on one scale.

    Returns
    -------
    rgb : ndarray of uint8, ``H x W x 3``
        Turbo colours (dark blue = ``vmin`` = far, dark red = ``vmax`` = near); invalid pixels black (Turbo
        itself never reaches pure black).
    """
    disp = np.asarray(disp, dtype=np.float64)
    if disp.ndim != 2:
        raise RiverbedError(f"disparity must be a 2-D array (H x W), got shape {disp.shape}")
    valid = np.isfinite(disp)
    rgb = np.zeros(disp.shape + (3,), np.uint8)
    if not valid.any():
        return rgb
    lo = float(disp[valid].min()) if vmin is None else float(vmin)
    hi = float(disp[valid].max()) if vmax is None else float(vmax)
    span = hi - lo if hi > lo else 1.0  # a constant map gets the lowest colour
    index = np.zeros(disp.shape, np.uint8)
    index[valid] = np.round(np.clip((disp[valid] - lo) / span, 0.0, 1.0) * 255).astype(np.uint8)
    colours = cv2.cvtColor(cv2.applyColorMap(index, cv2.COLORMAP_TURBO), cv2.COLOR_BGR2RGB)
    rgb[valid] = colours[valid]
    return rgb


def error_map(disp, gt, mask=None):
    """Colour the absolute disparity error per pixel, KITTI style.

    Parameters
    ----------
    disp : array_like, ``H x W``
        Predicted disparity in pixels, NaN invalid.
    gt : array_like, ``H x W``
        Ground-truth disparity in pixels, NaN where unknown.
    mask : array_like of bool, ``H x W``, optional
        Pixels to show (e.g. :func:`riverbed_cli.products.evaluate.evaluation_mask`, which leaves out the
        LiDAR pixels used as guidance); others are drawn black like pixels without ground truth.

    Returns
    -------
    rgb : ndarray of uint8, ``H x W x 3``
        ``|disp - gt|`` in the bins of :data:`ERROR_BINS` (dark blue <= 1/16 px, light blue <= 1 px, yellow
        to red above 1 px, dark red > 16 px; a bin holds errors up to and including its bound). Ground-truth
        pixels with no valid prediction are magenta (:data:`MISSING_COLOUR`); pixels without ground truth (or
        outside ``mask``) are black.
    """
    disp = np.asarray(disp, dtype=np.float64)
    gt = np.asarray(gt, dtype=np.float64)
    if disp.shape != gt.shape or disp.ndim != 2:
        raise RiverbedError(f"disparity and ground truth differ in shape: {_shape(disp)} vs {_shape(gt)}")
    shown = np.isfinite(gt)
    if mask is not None:
        mask = np.asarray(mask, dtype=bool)
        if mask.shape != gt.shape:
            raise RiverbedError(f"mask and ground truth differ in shape: {_shape(mask)} vs {_shape(gt)}")
        shown &= mask
    predicted = shown & np.isfinite(disp)
    err = np.abs(disp[predicted] - gt[predicted])
    bounds = np.array([b for b, _ in ERROR_BINS])
    colours = np.array([c for _, c in ERROR_BINS], np.uint8)
    rgb = np.zeros(gt.shape + (3,), np.uint8)
    # searchsorted(side="left"): an error equal to a bound falls in that bound's bin, (b[i-1], b[i]].
    rgb[predicted] = colours[np.searchsorted(bounds, err, side="left")]
    rgb[shown & ~predicted] = MISSING_COLOUR
    return rgb


def _shape(a):
    return "x".join(str(n) for n in np.shape(a))


def write_png(path, rgb, overwrite=False):
    """Write an RGB (``H x W x 3``) or grey (``H x W``) ``uint8`` image as PNG, atomically.

    Raises
    ------
    RiverbedError
        The path does not end in ``.png``, it exists and ``overwrite`` is false, its folder is missing, or the
        encoder fails.
    """
    path = Path(path)
    if path.suffix.lower() != ".png":
        shown = path.suffix or "(no extension)"
        raise RiverbedError(f"image output must be a .png file, not '{shown}'", path)
    rgb = np.asarray(rgb)
    if rgb.dtype != np.uint8 or not (rgb.ndim == 2 or (rgb.ndim == 3 and rgb.shape[2] == 3)):
        raise RiverbedError(f"PNG output needs uint8 HxW or HxWx3, got {rgb.dtype} {rgb.shape}", path)
    with atomic_output(path, overwrite) as tmp:
        write_png_file(tmp, rgb)
