"""Rectify two aerial frames from their interior and exterior orientation (``riverbed rectify``).

Two raw (unrectified) frame images and their orientation files become a rectified pair: ``left.png``,
``right.png`` and the pair file ``pair.yaml`` whose cameras are the exact cameras of the written images.

Orientation file (YAML, read with ``yaml.safe_load``; see ``docs/rectify.md`` for the full description)::

    interior:
      width: 1200                      # image size (px), optional: checked against the image
      height: 800
      pixel_size_mm: 0.004             # needed when a length below is in mm (square pixels)
      focal_length_mm: 12.0            # or focal_length_px
      principal_point_mm: [0.0, 0.0]   # x right, y up, from the image centre; or principal_point_px
      distortion: {k1: 0.0, k2: 0.0, k3: 0.0, p1: 0.0, p2: 0.0}   # optional, OpenCV's Brown model
    exterior:
      centre: [501184.89, 5002453.58, 840.57]    # projection centre X, Y, Z in the (projected) CRS
      omega_phi_kappa_deg: [0.11, -0.21, 19.75]  # or rotation: 3x3 matrix M (object -> image)
    crs: EPSG:32632                    # optional
    origin: [501230.0, 5002470.0, 200.0]   # optional: the pair file's local origin

Conventions
-----------
- Photogrammetric rotation (Wolf & Dewitt; Kraus): ``M = R3(kappa) R2(phi) R1(omega)`` maps object-space
  vectors to image space, ``[x, y, z]_image = M (X - C)``, image axes x right, y up, z towards the viewer
  (the camera looks along -z). ``R1(w) = [[1, 0, 0], [0, cos w, sin w], [0, -sin w, cos w]]``,
  ``R2(p) = [[cos p, 0, -sin p], [0, 1, 0], [sin p, 0, cos p]]``,
  ``R3(k) = [[cos k, sin k, 0], [-sin k, cos k, 0], [0, 0, 1]]``.
  Equivalently, the camera (image axes) is rotated from the object axes first by omega about X, then by phi
  about the once-rotated Y, then by kappa about the twice-rotated Z, each counter-clockwise seen from the
  positive axis. omega = phi = kappa = 0: looking straight down, image x east, top of the image north.
- OpenCV camera (x right, y down, z forward): ``R_cv = diag(1, -1, -1) M`` maps world to camera axes;
  ``[col, row, 1] ~ K distort(R_cv (X - C))``; pixel centres at integer coordinates.
- Distortion is OpenCV's Brown model on normalised coordinates (``x = X_cam / Z_cam``):
  ``x_d = x (1 + k1 r^2 + k2 r^4 + k3 r^6) + 2 p1 x y + p2 (r^2 + 2 x^2)`` (and likewise ``y_d``).
- World = the CRS's easting, northing, height, treated as Cartesian (no earth curvature or map-scale
  correction: fine for frames a few hundred metres across). The pair's cameras map *world minus origin*.

Rectification: ``cv2.stereoRectify`` (``STEREO_ZERO_DISPARITY``: both rectified cameras share the principal
point, so ``d = x_left - x_right = f B / depth > 0`` for every point in front) on the relative orientation,
``cv2.initUndistortRectifyMap`` and ``cv2.remap`` (bicubic). stereoRectify is given each camera turned about
its optical axis by 0, 90, 180 or -90 deg, whichever brings the baseline closest to its +x axis (towards the
right camera): the rectified images then share rows with the right camera to the right, also when the baseline
points against the left image's x axis (images turned by 180 deg), runs along its columns (90 deg) or the two
frames differ by 180 deg in kappa (strips flown in opposite directions: one image turned). The left output is
always made from the first image: nothing is swapped. ``info["turn_deg"]`` reports each image's turn.
"""

import logging
import math
import re
import time
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import yaml
from pyproj import CRS
from pyproj.exceptions import CRSError

from ..errors import RiverbedError
from ..io.atomic import atomic_output, check_output, check_output_folder
from ..io.images import MAX_PIXELS, read_image, write_png_file
from ..io.pairfile import write_pairfile
from ..io.textfiles import parse_yaml, read_text
from .cameras import PairGeometry, as_matrix, parse_number

log = logging.getLogger(__name__)

#: Orientation files larger than this are refused before parsing.
MAX_BYTES = 100_000
TOP_KEYS = ("interior", "exterior", "crs", "origin")
INTERIOR_KEYS = ("width", "height", "pixel_size_mm", "focal_length_mm", "focal_length_px",
                 "principal_point_mm", "principal_point_px", "distortion")
EXTERIOR_KEYS = ("centre", "omega_phi_kappa_deg", "rotation")
DISTORTION_KEYS = ("k1", "k2", "k3", "p1", "p2")
#: ``cv2.remap`` interpolation of the rectified images.
INTERPOLATION = cv2.INTER_CUBIC
#: Largest accepted deviation of a given rotation matrix from orthonormality (``max |M M^T - I|``).
ROTATION_TOL = 1e-5
#: Photogrammetric image axes (y up, z back) <-> OpenCV camera axes (y down, z forward).
_FLIP = np.diag([1.0, -1.0, -1.0])
_ZERO_DISPARITY = getattr(cv2, "STEREO_ZERO_DISPARITY", getattr(cv2, "CALIB_ZERO_DISPARITY", 1024))


# -- rotations -----------------------------------------------------------------------------------------------
def opk_to_matrix(omega, phi, kappa):
    """The photogrammetric rotation ``M = R3(kappa) R2(phi) R1(omega)`` (object -> image axes), angles in deg.

    ``M[2] = [sin phi, -sin omega cos phi, cos omega cos phi]``; see the module docstring for the axes.
    """
    w, p, k = (math.radians(a) for a in (omega, phi, kappa))
    cw, sw, cp, sp, ck, sk = math.cos(w), math.sin(w), math.cos(p), math.sin(p), math.cos(k), math.sin(k)
    r1 = np.array([[1.0, 0.0, 0.0], [0.0, cw, sw], [0.0, -sw, cw]])
    r2 = np.array([[cp, 0.0, -sp], [0.0, 1.0, 0.0], [sp, 0.0, cp]])
    r3 = np.array([[ck, sk, 0.0], [-sk, ck, 0.0], [0.0, 0.0, 1.0]])
    return r3 @ r2 @ r1


def matrix_to_opk(M):
    """Angles ``(omega, phi, kappa)`` in degrees of a photogrammetric rotation matrix (inverse of
    :func:`opk_to_matrix`; phi in [-90, 90])."""
    M = np.asarray(M, np.float64)
    phi = math.asin(max(-1.0, min(1.0, float(M[2, 0]))))
    omega = math.atan2(-float(M[2, 1]), float(M[2, 2]))
    kappa = math.atan2(-float(M[1, 0]), float(M[0, 0]))
    return math.degrees(omega), math.degrees(phi), math.degrees(kappa)


# -- orientation of one frame --------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class FrameOrientation:
    """Interior and exterior orientation of one frame image.

    Attributes
    ----------
    K : (3, 3) float64
        Camera matrix in pixels (pixel centres at integer coordinates).
    dist : (5,) float64
        Distortion ``k1, k2, p1, p2, k3`` (OpenCV's order and model).
    R : (3, 3) float64
        World -> OpenCV camera axes (x right, y down, z forward): ``diag(1, -1, -1) @ M``.
    centre : (3,) float64
        Projection centre, world coordinates (not minus origin).
    width, height : int or None
        Image size, when the file gives it (or the image it was checked against).
    crs : str or None
    origin : (3,) float64 or None
    path : Path or None
        The orientation file, for messages.
    """

    K: np.ndarray
    dist: np.ndarray
    R: np.ndarray
    centre: np.ndarray
    width: int | None = None
    height: int | None = None
    crs: str | None = None
    origin: np.ndarray | None = None
    path: Path | None = None

    @property
    def M(self):
        """Photogrammetric rotation matrix (object -> image axes, image y up, z towards the viewer)."""
        return _FLIP @ self.R

    @property
    def omega_phi_kappa(self):
        """``(omega, phi, kappa)`` in degrees."""
        return matrix_to_opk(self.M)

    def project(self, xyz):
        """Raw-image pixel coordinates ``(col, row)`` and depth of world points (N, 3), distortion included.

        ``xyz`` are world coordinates (not minus origin); float64 throughout.
        """
        X = np.asarray(xyz, np.float64).reshape(-1, 3) - self.centre
        cam = X @ self.R.T
        with np.errstate(divide="ignore", invalid="ignore"):
            x, y = cam[:, 0] / cam[:, 2], cam[:, 1] / cam[:, 2]
        k1, k2, p1, p2, k3 = self.dist
        r2 = x * x + y * y
        radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
        yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
        K = self.K
        return K[0, 0] * xd + K[0, 1] * yd + K[0, 2], K[1, 1] * yd + K[1, 2], cam[:, 2]


def _read_yaml(path):
    return parse_yaml(read_text(path, "orientation file", MAX_BYTES), Path(path))


def _mapping(data, key, allowed, path):
    """``data`` as a mapping with only ``allowed`` keys; ``key`` is its dotted name (None: the whole file)."""
    if not isinstance(data, dict):
        raise RiverbedError(f"{key}: expected a mapping with keys {', '.join(allowed)}, got "
                            f"{type(data).__name__}", path)
    unknown = [str(k) for k in data if k not in allowed]
    if unknown:
        name = unknown[0] if key is None else f"{key}.{unknown[0]}"
        where = "orientation file" if key is None else key
        raise RiverbedError(f"{name}: unknown key ({where} keys: {', '.join(allowed)})", path)
    return data


def _scalar(value, key, path, positive=False):
    x = parse_number(value)
    if x is None:
        raise RiverbedError(f"{key}: expected a number, got {value!r}", path)
    if not math.isfinite(x):
        raise RiverbedError(f"{key}: not finite: {value!r}", path)
    if positive and x <= 0:
        raise RiverbedError(f"{key}: must be positive, got {value!r}", path)
    return x


def _vector(value, n, key, path):
    try:
        return as_matrix(value, 1, n, key)
    except RiverbedError as e:
        raise RiverbedError(str(e), path) from None


def _size(value, key, path):
    integer = isinstance(value, int) and not isinstance(value, bool)
    if not integer or not 0 < value <= 10_000_000:
        raise RiverbedError(f"{key}: expected a positive integer (pixels), got {value!r}", path)
    return int(value)


def _one_of(data, keys, section, path, required=True):
    given = [k for k in keys if data.get(k) is not None]
    if len(given) > 1:
        raise RiverbedError(f"{section}.{given[1]}: give only one of {' or '.join(keys)}", path)
    if not given:
        if required:
            raise RiverbedError(f"{section}: missing {' or '.join(keys)}", path)
        return None
    return given[0]


def _check_crs(crs, key, path):
    if isinstance(crs, int) and not isinstance(crs, bool):
        crs = f"EPSG:{crs}"
    if not isinstance(crs, str) or not crs.strip():
        raise RiverbedError(f"{key}: expected a CRS such as EPSG:32632, got {crs!r}", path)
    try:
        c = CRS.from_user_input(crs)
    except CRSError:
        raise RiverbedError(f"{key}: unknown CRS '{crs}'", path) from None
    if c.is_geographic:
        raise RiverbedError(f"{key}: {crs} is geographic (degrees); projection centres need a projected CRS",
                            path)
    return crs


def orientation_from_dict(data, path=None, image_size=None):
    """A :class:`FrameOrientation` from the parsed contents of an orientation file.

    ``image_size`` ``(width, height)``, when known, is checked against ``interior.width``/``height`` and used
    for ``principal_point_mm`` (an offset from the image centre). Raises :class:`RiverbedError` naming
    ``path`` and the key (dotted, e.g. ``interior.focal_length_mm``).
    """
    if not isinstance(data, dict):
        raise RiverbedError("not an orientation file (expected a mapping with interior and exterior)", path)
    _mapping(data, None, TOP_KEYS, path)
    for key in ("interior", "exterior"):
        if data.get(key) is None:
            raise RiverbedError(f"{key}: missing", path)
    inner = _mapping(data["interior"], "interior", INTERIOR_KEYS, path)
    outer = _mapping(data["exterior"], "exterior", EXTERIOR_KEYS, path)

    # -- interior
    size = {}
    for key in ("width", "height"):
        if inner.get(key) is not None:
            size[key] = _size(inner[key], f"interior.{key}", path)
    if image_size is not None:
        for key, actual in zip(("width", "height"), image_size):
            if key in size and size[key] != actual:
                raise RiverbedError(f"interior.{key}: {size[key]} px, but the image is {actual} px", path)
            size[key] = int(actual)
    ps = None
    if inner.get("pixel_size_mm") is not None:
        ps = _scalar(inner["pixel_size_mm"], "interior.pixel_size_mm", path, positive=True)
    fkey = _one_of(inner, ("focal_length_mm", "focal_length_px"), "interior", path)
    f = _scalar(inner[fkey], f"interior.{fkey}", path, positive=True)
    pkey = _one_of(inner, ("principal_point_mm", "principal_point_px"), "interior", path)
    pp = _vector(inner[pkey], 2, f"interior.{pkey}", path)
    for key in (fkey, pkey):
        if key.endswith("_mm") and ps is None:
            raise RiverbedError(f"interior.pixel_size_mm: missing (needed for interior.{key})", path)
    if fkey == "focal_length_mm":
        f = f / ps
    if pkey == "principal_point_mm":
        if "width" not in size or "height" not in size:
            raise RiverbedError("interior.width: missing (principal_point_mm is an offset from the image "
                                "centre, which needs the image size)", path)
        cx = (size["width"] - 1) / 2 + pp[0] / ps
        cy = (size["height"] - 1) / 2 - pp[1] / ps
    else:
        cx, cy = float(pp[0]), float(pp[1])
    K = np.array([[f, 0.0, cx], [0.0, f, cy], [0.0, 0.0, 1.0]])
    coeffs = dict.fromkeys(DISTORTION_KEYS, 0.0)
    if inner.get("distortion") is not None:
        dist = _mapping(inner["distortion"], "interior.distortion", DISTORTION_KEYS, path)
        for key, value in dist.items():
            coeffs[key] = _scalar(value, f"interior.distortion.{key}", path)
    dist = np.array([coeffs["k1"], coeffs["k2"], coeffs["p1"], coeffs["p2"], coeffs["k3"]])

    # -- exterior
    if outer.get("centre") is None:
        raise RiverbedError("exterior.centre: missing (projection centre X, Y, Z)", path)
    centre = _vector(outer["centre"], 3, "exterior.centre", path)
    rkey = _one_of(outer, ("omega_phi_kappa_deg", "rotation"), "exterior", path)
    if rkey == "omega_phi_kappa_deg":
        M = opk_to_matrix(*_vector(outer[rkey], 3, "exterior.omega_phi_kappa_deg", path))
    else:
        try:
            M = as_matrix(outer[rkey], 3, 3, "exterior.rotation")
        except RiverbedError as e:
            raise RiverbedError(str(e), path) from None
        dev = float(np.abs(M @ M.T - np.eye(3)).max())
        if dev > ROTATION_TOL:
            raise RiverbedError(f"exterior.rotation: not a rotation matrix (M M^T differs from the identity "
                                f"by {dev:.3g})", path)
        if np.linalg.det(M) < 0:
            raise RiverbedError("exterior.rotation: determinant -1 (a reflection, not a rotation)", path)
        u, _, vt = np.linalg.svd(M)  # the nearest rotation: drop the rounding of printed matrices
        M = u @ vt

    crs = None
    if data.get("crs") is not None:
        crs = _check_crs(data["crs"], "crs", path)
    origin = None
    if data.get("origin") is not None:
        origin = _vector(data["origin"], 3, "origin", path)
    return FrameOrientation(K=K, dist=dist, R=_FLIP @ M, centre=centre, width=size.get("width"),
                            height=size.get("height"), crs=crs, origin=origin,
                            path=None if path is None else Path(path))


def load_orientation(path, image_size=None):
    """Read an orientation file (YAML) into a :class:`FrameOrientation`; see :func:`orientation_from_dict`."""
    return orientation_from_dict(_read_yaml(path), path, image_size)


def orientation_dict(K, R, centre, width, height, dist=None, crs=None, origin=None, pixel_size_mm=None):
    """The contents of an orientation file for an OpenCV camera (``R`` world -> camera, x right, y down).

    With ``pixel_size_mm`` the focal length and principal point are written in mm (the principal point as
    the offset from the image centre, y up), otherwise in pixels. Rotation as omega, phi, kappa (degrees).
    Floats are written at full precision by :func:`write_orientation`.
    """
    K = np.asarray(K, np.float64)
    if K[0, 0] != K[1, 1] or K[0, 1] != 0:
        raise RiverbedError("orientation files hold square pixels without skew (fx == fy, K[0][1] == 0)")
    inner = {"width": int(width), "height": int(height)}
    if pixel_size_mm:
        inner["pixel_size_mm"] = float(pixel_size_mm)
        inner["focal_length_mm"] = float(K[0, 0] * pixel_size_mm)
        inner["principal_point_mm"] = [float((K[0, 2] - (width - 1) / 2) * pixel_size_mm) + 0.0,
                                       float(-(K[1, 2] - (height - 1) / 2) * pixel_size_mm) + 0.0]
    else:
        inner["focal_length_px"] = float(K[0, 0])
        inner["principal_point_px"] = [float(K[0, 2]), float(K[1, 2])]
    if dist is not None:
        k1, k2, p1, p2, k3 = (float(v) for v in np.asarray(dist, np.float64).ravel()[:5])
        inner["distortion"] = {"k1": k1, "k2": k2, "k3": k3, "p1": p1, "p2": p2}
    opk = matrix_to_opk(_FLIP @ np.asarray(R, np.float64))
    out = {"interior": inner,
           "exterior": {"centre": [float(v) for v in centre], "omega_phi_kappa_deg": [float(a) for a in opk]}}
    if crs is not None:
        out["crs"] = str(crs)
    if origin is not None:
        out["origin"] = [float(v) for v in origin]
    return out


def write_orientation(path, data, comment=None, overwrite=False):
    """Write an orientation file (a dict from :func:`orientation_dict`) as YAML, atomically."""
    head = "".join(f"# {line}\n" for line in (comment or "").splitlines())
    text = head + yaml.safe_dump(data, default_flow_style=None, sort_keys=False, width=200)
    with atomic_output(path, overwrite) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return Path(path)


# -- the pair ------------------------------------------------------------------------------------------------
def _pair_frame(left, right):
    """Common CRS and origin of two orientations (checked), and the right file for messages."""
    crs = left.crs
    if right.crs is not None:
        if crs is None:
            crs = right.crs
        elif right.crs != crs:
            if CRS.from_user_input(right.crs) != CRS.from_user_input(crs):
                raise RiverbedError(f"crs: {right.crs} differs from the left orientation's {crs}", right.path)
    origin = left.origin
    if right.origin is not None:
        if origin is None:
            origin = right.origin
        elif not np.array_equal(right.origin, origin):
            raise RiverbedError(f"origin: {_fmt3(right.origin)} differs from the left orientation's "
                                f"{_fmt3(origin)}", right.path)
    if origin is None:
        # A local origin keeps UTM-sized numbers out of the matrices: the left centre, whole metres, height 0.
        origin = np.array([round(float(left.centre[0])), round(float(left.centre[1])), 0.0])
    return crs, np.asarray(origin, np.float64)


def _fmt3(v):
    return "(" + ", ".join(f"{float(x):.10g}" for x in v) + ")"


@dataclass(eq=False)
class Rectified:
    """A rectified pair in memory: what :func:`rectify_files` writes, and the maps that made it.

    ``maps[i] = (map_x, map_y)`` (float32, rectified size) give for every rectified pixel of image ``i``
    (0 left, 1 right) the raw-image pixel it was sampled from (``cv2.remap``); ``rotations[i]`` is the
    rotation from raw camera axes to rectified camera axes and ``K[i]`` the rectified camera matrix, so that
    ``pair.P_left == K[0] @ [R_rect | -R_rect (C_left - origin)]`` with ``R_rect = rotations[0] @ R_left``.
    """

    left: np.ndarray
    right: np.ndarray
    pair: PairGeometry
    maps: tuple
    rotations: tuple
    K: tuple
    info: dict


# In-plane rotations about the optical axis that turn the baseline to +x (OpenCV's rectified frame -> ours).
_QUARTER = {0: np.eye(3), 180: np.diag([-1.0, -1.0, 1.0]),
            90: np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]),
            -90: np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])}


def _rotated_principal_point(turn, cx, cy, w, h):
    """Principal point after turning a ``w x h`` rectified image (``cx, cy``) by ``turn`` (``_QUARTER``)."""
    if turn == 0:
        return cx, cy
    if turn == 180:
        return (w - 1) - cx, (h - 1) - cy
    if turn == 90:  # x' = f y_n + cx', y' = -f x_n + cy'
        return cy, (w - 1) - cx
    return (h - 1) - cy, cx  # -90: x' = -f y_n + cx', y' = f x_n + cy'


def _turn_towards(o, baseline):
    """The turn (a key of ``_QUARTER``) that brings ``baseline`` (world) closest to +x of camera ``o``."""
    b = o.R @ baseline
    return max(((0, b[0]), (180, -b[0]), (90, b[1]), (-90, -b[1])), key=lambda tb: tb[1])[0]


def _turned_camera(o, turn, W, H):
    """Camera matrix, distortion, rotation and image size of frame ``o`` (``W x H``) seen turned by ``turn``.

    The same camera with its image axes turned about the optical axis (``R' = Q R``, ``_QUARTER``): radial
    distortion is unchanged, the tangential coefficients turn with the axes.
    """
    K = o.K
    cx, cy = _rotated_principal_point(turn, float(K[0, 2]), float(K[1, 2]), W, H)
    fx, fy = (K[0, 0], K[1, 1]) if turn in (0, 180) else (K[1, 1], K[0, 0])
    k1, k2, p1, p2, k3 = o.dist
    p1, p2 = {0: (p1, p2), 180: (-p1, -p2), 90: (-p2, p1), -90: (p2, -p1)}[turn]
    Kt = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    return Kt, np.array([k1, k2, p1, p2, k3]), _QUARTER[turn] @ o.R, (W, H) if turn in (0, 180) else (H, W)


def rectify(left_image, left, right_image, right, alpha=0.0, size=None, interpolation=INTERPOLATION,
            _preturn=True):
    """Rectify two raw frames with OpenCV: ``stereoRectify`` + ``initUndistortRectifyMap`` + ``remap``.

    Parameters
    ----------
    left_image, right_image : ndarray
        Raw frames, ``H x W`` or ``H x W x 3``, uint8 or uint16, of the same size.
    left, right : FrameOrientation
        Their orientations. The first image is the reference (left) of the output.
    alpha : float
        stereoRectify's free scaling: 0 keeps only pixels valid in both rectified images (no black border), 1
        keeps every source pixel, -1 OpenCV's default scaling.
    size : (width, height), optional
        Rectified image size (default: the raw size, swapped when the images are turned by 90 deg).

    Returns
    -------
    Rectified
        Images, pair geometry (exactly rectified; ``origin`` and ``crs`` from the orientations), maps and an
        ``info`` dict (focal length, baseline, in-plane rotation applied, valid shares, ...).
    """
    t0 = time.perf_counter()
    if left_image.shape[:2] != right_image.shape[:2]:
        raise RiverbedError(
            f"the images differ in size ({left_image.shape[1]}x{left_image.shape[0]} vs "
            f"{right_image.shape[1]}x{right_image.shape[0]}); stereoRectify needs frames of one camera size")
    if left_image.shape != right_image.shape:
        raise RiverbedError(f"the images differ in channels ({left_image.shape} vs {right_image.shape})")
    if left_image.dtype != right_image.dtype:
        raise RiverbedError(f"the images differ in sample type ({left_image.dtype} vs {right_image.dtype})")
    H, W = left_image.shape[:2]
    if not (alpha == -1 or 0.0 <= alpha <= 1.0):
        raise RiverbedError(f"alpha must be between 0 and 1 (or -1 for OpenCV's default), got {alpha:g}")
    crs, origin = _pair_frame(left, right)
    C1, C2 = left.centre - origin, right.centre - origin
    B = float(np.linalg.norm(C2 - C1))
    if not B > 1e-9 * max(float(np.abs(C1).max()), 1.0):
        raise RiverbedError("exterior.centre: the two projection centres coincide (no baseline)", right.path)
    for o, other, name in ((left, C2, "left"), (right, C1, "right")):
        e = o.K @ (o.R @ (other - (o.centre - origin)))
        if abs(e[2]) > 1e-12 * np.linalg.norm(e):
            ex, ey = e[0] / e[2], e[1] / e[2]
            if -0.5 <= ex <= W - 0.5 and -0.5 <= ey <= H - 0.5:
                raise RiverbedError(
                    f"the epipole lies inside the {name} image, at ({ex:.1f}, {ey:.1f}): the cameras look "
                    "along the baseline, which planar rectification (stereoRectify) cannot handle", o.path)

    # stereoRectify sees each camera turned about its optical axis so that the baseline runs along +x (the
    # right camera to the right): its rotation averaging and scaling then work on a plain horizontal pair,
    # also when the frames differ by 90 or 180 deg in kappa (strips flown in opposite directions).
    turns = [_turn_towards(o, C2 - C1) if _preturn else 0 for o in (left, right)]
    (K1v, D1v, R1v, S1v), (K2v, D2v, R2v, S2v) = (_turned_camera(o, t, W, H)
                                                  for o, t in zip((left, right), turns))
    if S1v != S2v:
        log.warning("the frames are turned by 90 deg against each other: stereoRectify's valid-region "
                    "scaling (alpha) uses the left frame's size for both")
    R_rel = R2v @ R1v.T
    T = R2v @ (C1 - C2)
    out_size = S1v if size is None else (int(size[0]), int(size[1]))
    if min(out_size) < 1:
        raise RiverbedError(f"size must be positive, got {out_size[0]}x{out_size[1]}")

    def stereo(new_size):
        return cv2.stereoRectify(K1v, D1v, K2v, D2v, S1v, R_rel, T.reshape(3, 1), flags=_ZERO_DISPARITY,
                                 alpha=float(alpha), newImageSize=new_size)

    R1, R2, P1, P2 = stereo(out_size)[:4]
    # A fallback (the turns above make these cases rare): stereoRectify's vertical case (baseline along the
    # columns) is rectified at the swapped size and turned by 90 deg; a right camera on the left, by 180 deg.
    vertical = P2[1, 3] != 0.0
    if vertical:
        if size is None:
            out_size = (out_size[1], out_size[0])
        R1, R2, P1, P2 = stereo((out_size[1], out_size[0]))[:4]
    if not P1[0, 0] > 0:
        raise RiverbedError("stereoRectify failed (non-positive rectified focal length): the orientations of "
                            "the two frames differ too much for planar rectification")
    R_rect = R1 @ R1v  # world -> OpenCV's rectified axes (the same for both cameras)
    if np.abs(R2 @ R2v - R_rect).max() > 1e-9:
        raise RiverbedError("stereoRectify gave inconsistent rectified orientations (degenerate geometry)")
    b = R_rect @ (C2 - C1)
    if vertical:
        turn = 90 if b[1] > 0 else -90
    else:
        turn = 0 if b[0] > 0 else 180
    R_fin = _QUARTER[turn] @ R_rect
    # Make the rectified x axis exactly the baseline (a change of ~1e-16): the pair is *exactly* rectified.
    x = (C2 - C1) / B
    z = R_fin[2] - (R_fin[2] @ x) * x
    z /= np.linalg.norm(z)
    R_fin = np.stack([x, np.cross(z, x), z])
    f = float(P1[0, 0])
    w0, h0 = (out_size[1], out_size[0]) if vertical else out_size
    Ks = []
    for P in (P1, P2):
        cx, cy = _rotated_principal_point(turn, float(P[0, 2]), float(P[1, 2]), w0, h0)
        Ks.append(np.array([[f, 0.0, cx], [0.0, f, cy], [0.0, 0.0, 1.0]]))
    K1, K2 = Ks
    if K1[1, 2] != K2[1, 2]:
        raise RiverbedError("stereoRectify gave different rectified rows for the two images")
    P_left = K1 @ np.hstack([R_fin, (-R_fin @ C1)[:, None]])
    P_right = P_left.copy()
    P_right[0] = P_left[0] + (K2[0, 2] - K1[0, 2]) * P_left[2]
    P_right[0, 3] -= f * B
    pair = PairGeometry(P_left, P_right, origin=origin, crs=crs, width=out_size[0], height=out_size[1])

    rotations, maps, images, valid = [], [], [], []
    for o, K, img in ((left, K1, left_image), (right, K2, right_image)):
        Rr = R_fin @ o.R.T  # raw camera axes -> rectified camera axes
        mx, my = cv2.initUndistortRectifyMap(o.K, o.dist, Rr, K, out_size, cv2.CV_32FC1)
        images.append(cv2.remap(img, mx, my, interpolation, borderMode=cv2.BORDER_CONSTANT, borderValue=0))
        inside = (mx >= -0.5) & (mx <= W - 0.5) & (my >= -0.5) & (my <= H - 0.5)
        valid.append(round(float(inside.mean()), 6))
        rotations.append(Rr)
        maps.append((mx, my))
    # Each image's turn (multiple of 90 deg) and the small rotation left once the turn is undone.
    image_turns, angles = [], []
    for r in rotations:
        t = int(90 * round(math.degrees(math.atan2(r[0, 1], r[0, 0])) / 90)) % 360
        t = t - 360 if t > 180 else t
        image_turns.append(t)
        rest = r @ _QUARTER[t].T if t in _QUARTER else r
        angles.append(round(math.degrees(math.acos(max(-1.0, min(1.0, (np.trace(rest) - 1) / 2)))), 6))
    info = {"width": out_size[0], "height": out_size[1], "focal_px": f, "baseline": B, "fB": f * B,
            "turn_deg": image_turns, "alpha": alpha, "rectifying_rotation_deg": angles, "valid_share": valid,
            "origin": [float(v) for v in origin], "crs": crs, "seconds": round(time.perf_counter() - t0, 3)}
    for name, t in zip(("left", "right"), image_turns):
        if t:
            log.info("%s image turned by %d deg about its optical axis so that the baseline runs along the "
                     "rows with the right camera to the right (d >= 0)", name, t)
    return Rectified(images[0], images[1], pair, tuple(maps), tuple(rotations), (K1, K2), info)


OUTPUTS = ("left.png", "right.png", "pair.yaml")


def parse_size(value):
    """A rectified image size ``"WxH"`` (or a ``[W, H]`` list) -> ``(W, H)``; raises ValueError with a message."""
    if isinstance(value, (list, tuple)) and len(value) == 2 and all(isinstance(v, int) and v >= 1 for v in value):
        return int(value[0]), int(value[1])
    m = re.fullmatch(r"\s*(\d+)\s*[xX]\s*(\d+)\s*", value) if isinstance(value, str) else None
    if not m or int(m.group(1)) < 1 or int(m.group(2)) < 1:
        raise ValueError(f"expected WIDTHxHEIGHT in pixels, e.g. 1200x800, got {value!r}")
    return int(m.group(1)), int(m.group(2))


def check_alpha(value):
    """stereoRectify's free scaling: a number from 0 to 1, or -1 (OpenCV's default); raises ValueError."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not (value == -1 or 0.0 <= value <= 1.0):
        raise ValueError(f"expected a number from 0 to 1 (or -1), got {value!r}")
    return float(value)


def rectify_files(left_image, left_orientation, right_image, right_orientation, outdir, overwrite=False,
                  alpha=0.0, size=None, max_pixels=None):
    """Read two raw frames and their orientation files, rectify, write left.png, right.png, pair.yaml.

    ``outdir`` is created if missing (its parent must exist). All three outputs are written under temporary
    names and renamed into place only once all are complete; existing outputs are replaced only with
    ``overwrite``. Returns a summary dict (files and sizes, focal length, baseline, rotation, valid shares).
    """
    t0 = time.perf_counter()
    outdir = Path(outdir)
    check_output_folder(outdir)
    if outdir.is_dir():
        for name in OUTPUTS:
            check_output(outdir / name, overwrite)
    limit = MAX_PIXELS if max_pixels is None else max_pixels
    images, orients = [], []
    for img_path, or_path in ((left_image, left_orientation), (right_image, right_orientation)):
        img = read_image(img_path, limit)
        orients.append(load_orientation(or_path, image_size=(img.shape[1], img.shape[0])))
        images.append(img)
    if images[0].shape[:2] != images[1].shape[:2]:
        (w0, h0), (w1, h1) = images[0].shape[1::-1], images[1].shape[1::-1]
        raise RiverbedError(f"image is {w1}x{h1} but {left_image} is {w0}x{h0} (WxH); stereoRectify needs "
                            "frames of one camera size", right_image)
    result = rectify(images[0], orients[0], images[1], orients[1], alpha=alpha, size=size)
    outdir.mkdir(exist_ok=True)
    paths = [outdir / name for name in OUTPUTS]
    pair = result.pair.replace(left=paths[0].absolute(), right=paths[1].absolute())
    info = result.info
    names = [Path(p).name for p in (left_image, left_orientation, right_image, right_orientation)]
    comment = (f"Rectified by riverbed rectify from {names[0]} ({names[1]}) and {names[2]} ({names[3]}).\n"
               f"f = {info['focal_px']:.6f} px, baseline {info['baseline']:.6f}: d = x_left - x_right = "
               f"{info['fB']:.6f} / depth (px); images turned by {info['turn_deg'][0]} (left) and "
               f"{info['turn_deg'][1]} deg (right).")
    with atomic_output(paths[0], overwrite) as t_left, atomic_output(paths[1], overwrite) as t_right, \
            atomic_output(paths[2], overwrite) as t_pair:
        write_png_file(t_left, result.left)
        write_png_file(t_right, result.right)
        write_pairfile(t_pair, pair, comment=comment)
    files = {name: p.stat().st_size for name, p in zip(OUTPUTS, paths)}
    return {"outdir": str(outdir), "files": files, **info,
            "seconds": round(time.perf_counter() - t0, 3)}
