"""An RPC pair rectified over a region of interest, and its pair file (``riverbed rectify --rpc``; docs/rpc.md).

:func:`rectify_rpc_files` is what the command runs: two satellite images and their RPC models (any format
:func:`~riverbed_cli.geometry.rpc.read_rpc` reads), a region of interest of the left image and the terrain's height
range (from a DEM or given), rectified the s2p way (:mod:`riverbed_cli.geometry.rpc_rectify`: virtual matches,
affine fundamental matrix, rectifying similarities, horizontal registration, then the RPCs' relative pointing error
measured on tie points and removed as a row offset of the right image). It writes ``OUTDIR/left.tif``,
``OUTDIR/right.tif`` (the rectified images, the input's sample type and bands) and ``OUTDIR/pair.yaml``:

```yaml
left: left.tif                  # relative to the pair file
right: right.tif
rpc:
  left: {LINE_OFF: ..., ...}    # RPCModel.to_dict(), in the pixels of the left input file (crop offset applied)
  right: {LINE_OFF: ..., ...}   # the same for the right input file, with the pointing correction applied
rectification:                  # RPCRectification.to_dict(): input file pixel -> rectified pixel
  H_left: [[...], [...], [0, 0, 1]]
  H_right: [[...], [...], [0, 0, 1]]
  width: 613                    # of both rectified images (px)
  height: 614
  disparity: [0.0, 84.2]        # d = x_left - x_right over the height range, 5 px margins (px)
  heights: [452.2, 597.6]       # ellipsoidal (m)
  roi: [0, 0, 500, 500]         # col, row, width, height in the left input file (px)
  ...                           # fit and pointing figures
inputs: {left_image: ..., left_rpc: ..., left_crop_offset: [5000.0, 5000.0], ..., heights_from: ...}
```

With the recorded models, a ground point ``(lon, lat, h)`` is at ``H_left @ rpc.left.project(lon, lat, h)`` in
``left.tif`` and ``H_right @ rpc.right.project(lon, lat, h)`` in ``right.tif``, on the same row (the affine model's
error: 0.005 px over the Ventoux 500 x 500 crop) — :meth:`RPCPair.project`.

Crops: an image whose TIFF geotransform is a pure translation and that has no CRS (shareloc's and CARS's Ventoux
crops) is a crop of the full image its RPC file describes, starting at that translation (:func:`crop_offset`);
RPCs read from the image itself (GeoTIFF tags) are the image's own and are never shifted.
"""

import logging
import math
import os
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
import rasterio
import rasterio.windows
import yaml
from rasterio.errors import NotGeoreferencedWarning, RasterioIOError

from ..errors import RiverbedError
from ..io.atomic import atomic_output, c_stderr_silenced, check_output_folder
from ..io.images import MAX_PIXELS
from ..io.paths import require_file
from .cameras import as_matrix, parse_number
from .rpc import RPCModel, read_rpc
from .rpc_heights import (footprint_bounds, heights_from_dem, heights_from_lidar,  # noqa: F401
                          heights_from_tie_points, heights_to_ellipsoid)
from .rpc_rectify import (RPCRectification, apply_h, estimate_row_offset, rectify_rpc_pair, resample,
                          virtual_matches, with_row_offset)

log = logging.getLogger(__name__)

#: The files ``riverbed rectify --rpc`` writes into OUTDIR.
OUTPUTS = ("left.tif", "right.tif", "pair.yaml")
#: Keys of an RPC pair file.
RPC_PAIR_KEYS = ("left", "right", "rpc", "rectification", "inputs")
#: The smallest ROI side (px): the affine fit needs a spread of virtual matches.
MIN_ROI_PX = 8
#: Virtual row residual above which the ROI is too large for the affine model (a warning).
AFFINE_WARN_PX = 0.1
#: Extra source pixels read around the footprint of the rectified frame (bicubic needs 2).
READ_MARGIN_PX = 4


def parse_roi(text):
    """``"COL,ROW,W,H"`` -> a tuple of four ints (px); ``ValueError`` with a one-line message otherwise."""
    parts = [p.strip() for p in str(text).split(",")]
    try:
        vals = [int(p) for p in parts]
    except ValueError:
        vals = []
    if len(vals) != 4 or len(parts) != 4:
        raise ValueError(f"expected COL,ROW,W,H (four integers, px), got '{text}'")
    if vals[2] < MIN_ROI_PX or vals[3] < MIN_ROI_PX:
        raise ValueError(f"width and height must be at least {MIN_ROI_PX} px, got '{text}'")
    return tuple(vals)


#: plausible terrestrial heights (m, ellipsoidal or above a geoid): the Dead Sea shore (-430 m) and a geoid
#: undulation below, Everest (8849 m) and the undulation above; +-1e9 made the RPC inversion singular
MIN_HEIGHT, MAX_HEIGHT = -1000.0, 10000.0


def parse_heights(text):
    """``"LO,HI"`` -> ``(lo, hi)`` floats (m), ``lo < hi``, finite; ``ValueError`` with a one-line message."""
    parts = str(text).split(",")
    vals = [parse_number(p) for p in parts]
    if len(vals) != 2 or any(v is None or not math.isfinite(v) for v in vals):
        raise ValueError(f"expected LO,HI (two finite heights, m), got '{text}'")
    if not vals[0] < vals[1]:
        raise ValueError(f"LO must be below HI, got '{text}'")
    if vals[0] < MIN_HEIGHT or vals[1] > MAX_HEIGHT:
        raise ValueError(f"heights must lie from {MIN_HEIGHT:g} to {MAX_HEIGHT:g} m (the terrestrial range), got "
                         f"'{text}'")
    return vals[0], vals[1]


def crop_offset(path):
    """``(col0, row0)``: where a crop's first pixel lies in the full image, from its TIFF geotransform (px).

    shareloc's (and CARS's) crops of Pléiades products carry no CRS and a geotransform that is a pure translation
    by the crop's offset (the Ventoux crops: 5000/5000 and 4915/5162). Any other image -> ``(0.0, 0.0)`` (an
    image without a geotransform reads as the identity; a georeferenced image's transform is map coordinates).
    """
    with _open(path) as ds:
        t, crs = ds.transform, ds.crs
    if crs is not None or (t.a, t.b, t.d, t.e) != (1.0, 0.0, 0.0, 1.0):
        return 0.0, 0.0
    return float(t.c), float(t.f)


def _open(path):
    path = require_file(path)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", NotGeoreferencedWarning)
            return rasterio.open(path)
    except RasterioIOError as e:
        raise RiverbedError(f"cannot read the image ({str(e).splitlines()[0]})", path) from None


def relative_path(target, folder):
    """``target`` relative to ``folder`` as a POSIX string (absolute when on another drive)."""
    target = Path(target).absolute()
    try:
        return Path(os.path.relpath(target, Path(folder).absolute())).as_posix()
    except ValueError:  # another drive (Windows)
        return target.as_posix()


@dataclass
class RPCPair:
    """A rectified RPC pair as its pair file describes it (:func:`rectify_rpc_files` writes it).

    ``rpc_left`` / ``rpc_right`` are the models of the two *input* image files' pixels (the right one with the
    pointing correction); ``rectification`` maps those pixels to the rectified images ``left`` / ``right``.
    """

    rpc_left: object
    rpc_right: object
    rectification: RPCRectification
    left: Path = None
    right: Path = None
    inputs: dict = field(default_factory=dict)
    #: CRS of triangulated points (``riverbed dsm``): None is the UTM zone of the scene (rpc_geometry.scene_utm).
    crs: str = None
    kind = "rpc"

    @property
    def registration(self):
        """Identity (4 x 4): ``--lidar`` clouds merged into an RPC pair's DSM are in its output CRS already."""
        return np.eye(4)

    @property
    def width(self):
        return int(self.rectification.size[0])

    @property
    def height(self):
        return int(self.rectification.size[1])

    @property
    def image_size(self):
        """``(height, width)`` of the rectified images (px)."""
        return self.height, self.width

    @property
    def disparity(self):
        """``(d_min, d_max)`` of ``d = x_left - x_right`` over the height range, margins included (px)."""
        return tuple(self.rectification.disparity)

    @property
    def heights(self):
        return tuple(self.rectification.heights)

    @property
    def roi(self):
        return tuple(self.rectification.roi)

    def project(self, lon, lat, h):
        """Ground -> rectified pixels: ``(x_left, y_left, x_right, y_right)`` (px, pixel centres at integers).

        Parameters
        ----------
        lon, lat : array_like
            WGS 84 longitude and latitude (degrees).
        h : array_like
            Height above the WGS 84 ellipsoid (m).
        """
        xl, yl = apply_h(self.rectification.H_left, *self.rpc_left.project(lon, lat, h))
        xr, yr = apply_h(self.rectification.H_right, *self.rpc_right.project(lon, lat, h))
        return xl, yl, xr, yr


def rpc_pair_to_dict(pair, folder=None):
    """A plain dict of an :class:`RPCPair` (the pair file's content); image paths relative to ``folder``."""
    out = {}
    for key in ("left", "right"):
        value = getattr(pair, key)
        if value is not None:
            out[key] = relative_path(value, folder) if folder is not None else str(value)
    out["rpc"] = {"left": pair.rpc_left.to_dict(), "right": pair.rpc_right.to_dict()}
    out["rectification"] = pair.rectification.to_dict()
    if pair.inputs:
        out["inputs"] = pair.inputs
    return out


def _pair_list(value, n, key, path, integer=False):
    if not isinstance(value, (list, tuple)) or len(value) != n:
        raise RiverbedError(f"{key}: expected {n} numbers, got {value!r}", path)
    out = []
    for v in value:
        x = parse_number(v)
        if x is None or not math.isfinite(x) or (integer and x != int(x)):
            raise RiverbedError(f"{key}: expected {n} finite {'integers' if integer else 'numbers'}, got {value!r}",
                                path)
        out.append(int(x) if integer else x)
    return tuple(out)


#: the least change of disparity with height (px per m) a stereo pair has: 1 px per km is no stereo (the same image,
#: or one viewing direction, twice); real pairs have about 0.1 to 1 px per m
MIN_DISPARITY_PER_METRE = 1e-3


def check_baseline(rpc_left, rpc_right, rectification, path):
    """Refuse a pair whose disparity does not change with height (:data:`MIN_DISPARITY_PER_METRE`) at the centre of
    its left ROI: no height can be triangulated from it. ``path``: the file named in the message."""
    x, y, w, h = rectification.roi
    cx, cy = np.full(2, x + 0.5 * w), np.full(2, y + 0.5 * h)
    heights = np.asarray(rectification.heights, np.float64)
    with np.errstate(all="ignore"):
        lon, lat = rpc_left.localize(cx, cy, heights)
        u1, _ = apply_h(rectification.H_left, cx, cy)
        u2, _ = apply_h(rectification.H_right, *rpc_right.project(lon, lat, heights))
        slope = abs(float(np.diff(u1 - u2)[0] / np.diff(heights)[0]))
    if not slope >= MIN_DISPARITY_PER_METRE:
        raise RiverbedError(f"the two views have no stereo baseline: the disparity changes by {slope * 1000:.2f} px "
                            "per km of height (the same image, or one viewing direction, twice?)", path)


def rpc_pair_from_dict(data, path):
    """Validate the mapping of an RPC pair file (``path``: for messages and relative image paths) -> :class:`RPCPair`.

    Raises :class:`RiverbedError` (``PATH: KEY: problem``) for unknown keys, an incomplete RPC model, matrices that
    are not invertible affinities, or sizes and ranges that are not numbers.
    """
    path = Path(path)
    unknown = [str(k) for k in data if k not in RPC_PAIR_KEYS]
    if unknown:
        raise RiverbedError(f"unknown key '{unknown[0]}' (RPC pair file keys: {', '.join(RPC_PAIR_KEYS)})", path)
    rpc = data.get("rpc")
    if not isinstance(rpc, dict) or set(rpc) != {"left", "right"}:
        raise RiverbedError("rpc: expected a mapping with the RPC models 'left' and 'right'", path)
    models = {}
    for side in ("left", "right"):
        if not isinstance(rpc[side], dict):
            raise RiverbedError(f"rpc.{side}: expected a mapping of RPC fields (LINE_OFF, ...)", path)
        try:
            models[side] = RPCModel.from_dict(rpc[side], fmt="pair-file")
        except RiverbedError as e:
            raise RiverbedError(f"rpc.{side}: {e}", path) from None
    rect = data.get("rectification")
    if not isinstance(rect, dict):
        raise RiverbedError("rectification: missing (H_left, H_right, width, height, disparity, heights, roi)", path)
    for key in ("H_left", "H_right", "width", "height", "disparity", "heights", "roi"):
        if key not in rect:
            raise RiverbedError(f"rectification.{key}: missing", path)
    H = {}
    for key in ("H_left", "H_right"):
        try:
            H[key] = as_matrix(rect[key], 3, 3, f"rectification.{key}")
        except RiverbedError as e:
            raise RiverbedError(str(e), path) from None
        if not np.array_equal(H[key][2], [0.0, 0.0, 1.0]) or abs(np.linalg.det(H[key][:2, :2])) < 1e-12:
            raise RiverbedError(f"rectification.{key}: not an invertible affinity (last row [0, 0, 1])", path)
    size = []
    for key in ("width", "height"):
        v = rect[key]
        if isinstance(v, bool) or not isinstance(v, int) or v < 1:
            raise RiverbedError(f"rectification.{key}: expected a positive integer, got {v!r}", path)
        size.append(v)
    disparity = _pair_list(rect["disparity"], 2, "rectification.disparity", path)
    heights = _pair_list(rect["heights"], 2, "rectification.heights", path)
    roi = _pair_list(rect["roi"], 4, "rectification.roi", path, integer=True)
    if disparity[0] > disparity[1] or heights[0] >= heights[1]:
        raise RiverbedError("rectification: disparity and heights must be (low, high) ranges", path)
    info = {k: v for k, v in rect.items() if k not in ("H_left", "H_right", "width", "height", "disparity",
                                                         "heights", "roi")}
    rectification = RPCRectification(H_left=H["H_left"], H_right=H["H_right"], size=tuple(size),
                                     disparity=disparity, heights=heights, roi=roi, info=info)
    check_baseline(models["left"], models["right"], rectification, path)
    images = {}
    for key in ("left", "right"):
        value = data.get(key)
        if value is not None:
            if not isinstance(value, str) or not value:
                raise RiverbedError(f"{key}: expected a file name, got {value!r}", path)
            images[key] = Path(os.path.normpath((path.parent / value).absolute()))
    inputs = data.get("inputs") or {}
    if not isinstance(inputs, dict):
        raise RiverbedError("inputs: expected a mapping", path)
    return RPCPair(rpc_left=models["left"], rpc_right=models["right"], rectification=rectification,
                   inputs=inputs, **images)


# ---------------------------------------------------------------------------------------------------------------
# rectify_rpc_files


def _window_of(H, size, ds):
    """The source window (clipped to the image) that the rectified frame of affinity ``H`` samples, or None."""
    w, h = size
    u = np.array([-0.5, w - 0.5, -0.5, w - 0.5])
    v = np.array([-0.5, -0.5, h - 0.5, h - 0.5])
    x, y = apply_h(np.linalg.inv(H), u, v)
    c0 = max(int(np.floor(x.min())) - READ_MARGIN_PX, 0)
    r0 = max(int(np.floor(y.min())) - READ_MARGIN_PX, 0)
    c1 = min(int(np.ceil(x.max())) + READ_MARGIN_PX + 1, ds.width)
    r1 = min(int(np.ceil(y.max())) + READ_MARGIN_PX + 1, ds.height)
    if c1 <= c0 or r1 <= r0:
        return None
    return rasterio.windows.Window(c0, r0, c1 - c0, r1 - r0)


def _resample_window(ds, H, size, path):
    """The image of ``ds`` resampled into the rectified frame of ``H`` (bands last when more than one)."""
    window = _window_of(H, size, ds)
    if window is None:
        shape = (size[1], size[0]) if ds.count == 1 else (size[1], size[0], ds.count)
        return np.zeros(shape, ds.dtypes[0])
    try:
        data = ds.read(window=window)
    except RasterioIOError as e:
        raise RiverbedError(f"cannot read the image ({str(e).splitlines()[0]})", path) from None
    T = np.array([[1, 0, window.col_off], [0, 1, window.row_off], [0, 0, 1]], np.float64)
    img = data[0] if data.shape[0] == 1 else np.moveaxis(data, 0, -1)
    out = resample(img, H @ T, size)
    return out.astype(data.dtype, copy=False)


def _rectified(left_image, right_image, H_left, H_right, size):
    """Both images resampled by ``H_left`` and ``H_right`` into frames of ``size`` (w, h), and their valid areas."""
    with _open(left_image) as a, _open(right_image) as b:
        sides = ((a, H_left, left_image), (b, H_right, right_image))
        images = [_resample_window(ds, H, size, path) for ds, H, path in sides]
        valid = tuple(_valid_area(ds, H, size) for ds, H, _ in sides)
    return images[0], images[1], valid


def _grey(img):
    return img.astype(np.float32) if img.ndim == 2 else img.astype(np.float32).mean(axis=2)


def _valid_area(ds, H, size):
    """The rectified pixels inside the image of ``ds``: those whose centre the affinity ``H`` maps back inside its
    extent (the image's outline mapped by ``H``, a parallelogram, filled), (h, w) bool, or None when every one is."""
    w, h = ds.width, ds.height
    corners = np.array([[-0.5, -0.5, 1], [w - 0.5, -0.5, 1], [w - 0.5, h - 0.5, 1], [-0.5, h - 0.5, 1]]).T
    outline = (H @ corners)[:2].T
    valid = np.zeros((int(size[1]), int(size[0])), np.uint8)
    # 4 fractional bits: the outline to 1/16 px; a pixel counts when its centre lies inside
    cv2.fillConvexPoly(valid, np.round(outline * 16).astype(np.int32), 1, lineType=cv2.LINE_8, shift=4)
    valid = valid > 0
    return None if valid.all() else valid


def _write_tiff(path, img, valid=None):
    # valid: the image's valid area, written as its GDAL mask (read back by io.windowed.valid_area_source)
    bands = img[np.newaxis] if img.ndim == 2 else np.moveaxis(img, -1, 0)
    with warnings.catch_warnings(), c_stderr_silenced():  # a failed write is found when it is checked (io/atomic)
        warnings.simplefilter("ignore", NotGeoreferencedWarning)
        with rasterio.Env(GDAL_TIFF_INTERNAL_MASK=True), \
                rasterio.open(path, "w", driver="GTiff", width=bands.shape[2], height=bands.shape[1],
                              count=bands.shape[0], dtype=bands.dtype, compress="deflate") as ds:
            ds.write(bands)
            if valid is not None:
                ds.write_mask(np.where(valid, 255, 0).astype(np.uint8))


def _row_residual(pair, n=21, n_heights=7):
    """Row difference (px) of virtual ground points (left ROI grid x heights) through the recorded models."""
    x, y, w, h = pair.roi
    gx, gy, gh = np.meshgrid(np.linspace(x, x + w - 1, n), np.linspace(y, y + h - 1, n),
                             np.linspace(*pair.heights, n_heights), indexing="ij")
    lon, lat = pair.rpc_left.localize(gx.ravel(), gy.ravel(), gh.ravel())
    _, yl, _, yr = pair.project(lon, lat, gh.ravel())
    dy = (yl - yr)[np.isfinite(yl - yr)]
    return float(np.max(np.abs(dy))), float(np.sqrt(np.mean(dy ** 2)))


def read_rpc_inputs(left_image, left_rpc, right_image, right_rpc):
    """The two images' RPC models (crop offsets applied), sizes and crop offsets.

    Returns
    -------
    models : (RPCModel, RPCModel)
        Left and right, in the pixels of the image files (a separate RPC file of a crop shifted by
        :func:`crop_offset`; RPCs read from the image itself never are).
    sizes : ((W, H), (W, H))
        The images' sizes (px).
    offsets : ((col0, row0), (col0, row0))
        The crop offsets applied (px).
    """
    models, sizes, offsets = [], [], []
    for img_path, rpc_path in ((left_image, left_rpc), (right_image, right_rpc)):
        with _open(img_path) as ds:
            sizes.append((ds.width, ds.height))
        model = read_rpc(rpc_path)
        same = Path(rpc_path).resolve() == Path(img_path).resolve()
        off = (0.0, 0.0) if same else crop_offset(img_path)
        offsets.append(off)
        models.append(model.shifted(*off))
    return tuple(models), tuple(sizes), tuple(offsets)


def check_roi(roi, size, path, option="--roi"):
    """``roi`` as four ints, inside an image of ``size`` (W, H); a one-line :class:`RiverbedError` otherwise."""
    W, H = size
    x, y, w, h = (int(v) for v in roi)
    if x < 0 or y < 0 or x + w > W or y + h > H:
        raise RiverbedError(f"{option} {x},{y},{w},{h} is outside the {W}x{H} image (it covers cols {x}..{x + w - 1}, "
                            f"rows {y}..{y + h - 1})", path)
    return x, y, w, h


def right_share(rpc_left, rpc_right, roi, heights, right_size, n=11, n_heights=5):
    """Share of virtual matches (an ``n x n`` grid over the left ROI x ``n_heights`` heights over ``heights``) whose
    projection falls inside the right image of ``right_size`` (W, H), and their right columns and rows."""
    _, _, x2, y2, _ = virtual_matches(rpc_left, rpc_right, roi, heights, n, n_heights)
    W2, H2 = right_size
    inside = (x2 >= -0.5) & (x2 <= W2 - 0.5) & (y2 >= -0.5) & (y2 <= H2 - 0.5)
    return (float(inside.mean()) if inside.size else 0.0), x2, y2


def rectify_rpc_files(left_image, left_rpc, right_image, right_rpc, outdir, roi=None, dem=None, heights=None,
                      vertical=None, pointing=True, overwrite=False, max_pixels=MAX_PIXELS, lidar=None,
                      lidar_crs=None, classes=None, drop_classes=(7, 18),
                      pointing_hint="--no-pointing-correction"):
    """Rectify an RPC pair over a ROI of the left image; write left.tif, right.tif and pair.yaml into ``outdir``.

    Parameters
    ----------
    left_image, right_image : str or Path
        The images (any raster GDAL reads; only the windows the rectified frame needs are read).
    left_rpc, right_rpc : str or Path
        Their RPC models (:func:`~riverbed_cli.geometry.rpc.read_rpc`; the image itself for GeoTIFF RPC tags).
        A separate RPC file of a crop is shifted by the crop's offset (:func:`crop_offset`).
    outdir : str or Path
        Output folder, created if missing (its parent must exist).
    roi : (col, row, width, height), optional
        Region of the left image (px), inside it; default the whole image.
    dem : str or Path, optional
        A DEM over the ROI (``read_dem``): the height range is its range under the ROI's footprint +- 20 m.
    heights : (lo, hi), optional
        The height range instead of a DEM (m, ellipsoidal unless ``vertical`` says otherwise).
    vertical : str, optional
        The vertical datum of the DEM when its file does not say, or of ``heights`` (``"ellipsoid"``,
        ``"EPSG:5773"`` = EGM96).
    pointing : bool
        Measure the relative pointing error on tie points and remove it (the right image moved by rows).
    pointing_hint : str
        How the caller turns the correction off, named when it fails (a block manifest's ``pointing: false``).
    overwrite : bool
        Replace existing outputs.
    max_pixels : int
        Refuse a rectified frame larger than this (width x height).
    lidar : path or sequence of paths, optional
        LiDAR clouds instead of a DEM: the height range is that of their points under the ROI +- 20 m
        (:func:`heights_from_lidar`; ``lidar_crs`` their CRS when the files do not state it, ``classes`` /
        ``drop_classes`` the ASPRS classes kept / dropped).

    Returns
    -------
    dict
        The summary ``--json`` prints: files and sizes, rectified size, ROI, heights, disparity range, pointing
        row offset, virtual row residuals (px), seconds.
    """
    t0 = time.perf_counter()
    outdir = Path(outdir)
    check_output_folder(outdir, OUTPUTS, overwrite, inputs=[left_image, left_rpc, right_image, right_rpc, dem])
    if lidar is not None and not isinstance(lidar, (str, os.PathLike)) and not len(lidar):
        lidar = None
    if sum(v is not None for v in (dem, heights, lidar)) > 1:
        raise RiverbedError("give the terrain's height range by one of --dem DEM, --heights LO,HI or --lidar CLOUD "
                            "(or none: from tie points)")
    if lidar is not None and vertical is not None:
        raise RiverbedError("--vertical does not apply to --lidar (the cloud's CRS gives its heights' datum)")
    (rpc_l, rpc_r), sizes, offsets = read_rpc_inputs(left_image, left_rpc, right_image, right_rpc)
    (W, H), (W2, H2) = sizes
    roi = check_roi((0, 0, W, H) if roi is None else roi, (W, H), left_image)
    x, y, w, h = roi
    if dem is not None:
        hrange, datum = heights_from_dem(rpc_l, roi, dem, vertical)
        heights_from = f"DEM {Path(dem).name} ({datum}) under the ROI +- 20 m"
    elif lidar is not None:
        hrange, found = heights_from_lidar(rpc_l, roi, lidar, lidar_crs, classes, drop_classes)
        names = [Path(lidar).name] if isinstance(lidar, (str, os.PathLike)) else [Path(p).name for p in lidar]
        heights_from = (f"LiDAR {', '.join(names)} ({found['points']} points under the ROI, "
                        f"{found['range'][0]:.1f}..{found['range'][1]:.1f} m) +- 20 m")
    elif heights is not None:
        hrange = heights_to_ellipsoid(heights, rpc_l, roi, vertical)
        heights_from = "--heights" + (f" ({vertical})" if vertical else " (ellipsoidal)")
    else:
        hrange, n = heights_from_tie_points(rpc_l, rpc_r, roi, lambda *a: _rectified(left_image, right_image, *a))
        heights_from = f"tie points ({n} over the RPCs' height domain) +- 20 m"
    # images that do not overlap: the ROI's ground, seen over the height range, must fall in the right image
    share, x2, y2 = right_share(rpc_l, rpc_r, roi, hrange, (W2, H2))
    if share == 0:
        where = (f"cols {x2.min():.0f}..{x2.max():.0f}, rows {y2.min():.0f}..{y2.max():.0f}" if x2.size
                 else "nowhere")
        raise RiverbedError(f"does not overlap the left image's ROI (its RPC sees the ROI's ground at {where}, "
                            f"outside this {W2}x{H2} image)", right_image)
    rect = rectify_rpc_pair(rpc_l, rpc_r, roi, hrange)
    check_baseline(rpc_l, rpc_r, rect, right_image)
    out_w, out_h = rect.size
    if max_pixels is not None and out_w * out_h > max_pixels:
        raise RiverbedError(f"the rectified ROI would be {out_w}x{out_h} px, more than --max-pixels {max_pixels}")
    with _open(left_image) as ds:
        rect_left = _resample_window(ds, rect.H_left, rect.size, left_image)
        left_valid = _valid_area(ds, rect.H_left, rect.size)
    with _open(right_image) as ds_right:
        rect_right = _resample_window(ds_right, rect.H_right, rect.size, right_image)
        n_tie, offset = 0, 0.0
        if pointing:
            try:
                offset, n_tie = estimate_row_offset(_grey(rect_left), _grey(rect_right), rect.disparity)
            except RiverbedError as e:
                raise RiverbedError(f"{e} (with {right_image}; {pointing_hint} rectifies without it)",
                                    left_image) from None
            rect = with_row_offset(rect, offset)
            rect_right = _resample_window(ds_right, rect.H_right, rect.size, right_image)
        valid_areas = (left_valid, _valid_area(ds_right, rect.H_right, rect.size))
    # the pointing correction as a shift of the right model: H_right(rpc_r'(X)) has the row of H_left(rpc_l(X))
    L = rect.H_right[:2, :2]
    shift = np.linalg.solve(L, [0.0, -offset]) if offset else np.zeros(2)
    rpc_r = rpc_r.shifted(-shift[0], -shift[1])
    rect.info.update({"pointing_tie_points": n_tie, "right_rpc_shift_px": [float(shift[0]), float(shift[1])]})
    if not pointing:
        rect.info["pointing_row_offset_px"] = None
    outdir_paths = [outdir / name for name in OUTPUTS]
    names = {"left_image": left_image, "left_rpc": left_rpc, "right_image": right_image, "right_rpc": right_rpc}
    inputs = {k: relative_path(v, outdir) for k, v in names.items()}
    inputs.update({"left_crop_offset": list(offsets[0]), "right_crop_offset": list(offsets[1]),
                   "heights_from": heights_from})
    pair = RPCPair(rpc_left=rpc_l, rpc_right=rpc_r, rectification=rect, left=outdir_paths[0].absolute(),
                   right=outdir_paths[1].absolute(), inputs=inputs)
    check_max, check_rms = _row_residual(pair)
    if check_max > AFFINE_WARN_PX:
        log.warning("the affine model leaves %.3f px of rows between virtual matches: a smaller --roi is more "
                    "exact", check_max)
    data = rpc_pair_to_dict(pair, outdir)
    comment = (f"Rectified by riverbed rectify --rpc from {Path(left_image).name} ({Path(left_rpc).name}) and "
               f"{Path(right_image).name} ({Path(right_rpc).name}): ROI {x},{y},{w},{h}, heights "
               f"{hrange[0]:.1f}..{hrange[1]:.1f} m (ellipsoidal), d = x_left - x_right in "
               f"{rect.disparity[0]:.1f}..{rect.disparity[1]:.1f} px.\n"
               "rpc: the models of the input files' pixels (crop offsets and the pointing correction applied); "
               "rectification: input pixel -> rectified pixel.")
    text = "".join(f"# {line}\n" for line in comment.splitlines())
    text += yaml.safe_dump(data, default_flow_style=None, sort_keys=False, width=200)
    outdir.mkdir(exist_ok=True)
    with atomic_output(outdir_paths[0], overwrite) as t_left, atomic_output(outdir_paths[1], overwrite) as t_right, \
            atomic_output(outdir_paths[2], overwrite) as t_pair:
        _write_tiff(t_left, rect_left, valid_areas[0])
        _write_tiff(t_right, rect_right, valid_areas[1])
        t_pair.write_text(text, encoding="utf-8")
    return {"outdir": str(outdir), "files": {n: p.stat().st_size for n, p in zip(OUTPUTS, outdir_paths)},
            "width": out_w, "height": out_h, "roi": list(roi), "heights": [float(v) for v in hrange],
            "heights_from": heights_from, "disparity": [float(v) for v in rect.disparity],
            "disparity_per_metre": rect.info["disparity_per_metre"],
            "pointing_row_offset_px": rect.info["pointing_row_offset_px"], "pointing_tie_points": n_tie,
            "virtual_row_residual_max_px": check_max, "virtual_row_residual_rms_px": check_rms,
            "virtual_row_residual_fit_max_px": rect.info["virtual_row_residual_max_px"],
            "crop_offsets": [list(offsets[0]), list(offsets[1])],
            "seconds": round(time.perf_counter() - t0, 3)}
