"""Orientation files of frame images: interior and exterior orientation of one frame, read, checked and
written (the input of ``riverbed rectify``, see :mod:`riverbed_cli.geometry.rectify`).

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
"""

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml
from pyproj import CRS
from pyproj.exceptions import CRSError

from ..errors import RiverbedError
from ..io.atomic import atomic_output
from ..io.textfiles import load_text_data
from .cameras import as_matrix, parse_number

#: Orientation files larger than this are refused before parsing.
MAX_BYTES = 100_000
TOP_KEYS = ("interior", "exterior", "crs", "origin")
INTERIOR_KEYS = ("width", "height", "pixel_size_mm", "focal_length_mm", "focal_length_px",
                 "principal_point_mm", "principal_point_px", "distortion")
EXTERIOR_KEYS = ("centre", "omega_phi_kappa_deg", "rotation")
DISTORTION_KEYS = ("k1", "k2", "k3", "p1", "p2")
#: Largest accepted deviation of a given rotation matrix from orthonormality (``max |M M^T - I|``).
ROTATION_TOL = 1e-5
#: Photogrammetric image axes (y up, z back) <-> OpenCV camera axes (y down, z forward).
_FLIP = np.diag([1.0, -1.0, -1.0])


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
    return load_text_data(Path(path), "orientation file", MAX_BYTES, fmt="yaml")[0]


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


def scalar(value, key, path, positive=False):
    """``value`` as a finite float (positive if asked), or a :class:`RiverbedError` naming ``key`` in ``path``."""
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
        ps = scalar(inner["pixel_size_mm"], "interior.pixel_size_mm", path, positive=True)
    fkey = _one_of(inner, ("focal_length_mm", "focal_length_px"), "interior", path)
    f = scalar(inner[fkey], f"interior.{fkey}", path, positive=True)
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
            coeffs[key] = scalar(value, f"interior.distortion.{key}", path)
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
