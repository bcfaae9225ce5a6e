"""The geometry of a rectified stereo pair (:class:`PairGeometry`) and importers for benchmark calibrations.

A pair is two 3 x 4 projection matrices that map *world minus origin* (homogeneous, float64) to pixels of the
rectified left and right images, an ``origin`` subtracted from world coordinates first (so large UTM values
never reach the matrices), and a 4 x 4 ``registration`` that maps LiDAR coordinates to world coordinates:

    world = registration @ [x_lidar, y_lidar, z_lidar, 1]
    [u, v, w] = P @ [world - origin, 1];  x = u / w,  y = v / w

Rectified means the two images share their rows. Exactly (0-based indices, as in error messages): rows 1 and 2
of the left 3 x 3 blocks are equal and the first rows differ only by ``s * (row 2)`` (a constant horizontal
image shift: Middlebury's ``doffs``); the 4th columns may differ in their first entry (the baseline). A small
difference in the 4th column's entries [1][3] and [2][3] (a camera centre slightly off the baseline, as in
KITTI's P2/P3: 2.7 mm vertically) is accepted when it is at most 5 % of the horizontal term: it offsets the
right image's rows by a depth-dependent fraction of a pixel, which
:func:`riverbed_cli.geometry.projection.project_cloud` measures per point (it drops points off by more than
1 px and logs a warning).

Conventions: pixel centres at integer coordinates; ``d = x_left - x_right`` (px); depth is the distance along
the left camera's optical axis, in world units, positive in front of the camera.
"""

import logging
import math
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import RiverbedError

log = logging.getLogger(__name__)

#: Relative tolerance of the rectified-pair check (of the largest entry of the left 3 x 3 block).
RECTIFIED_RTOL = 1e-9
#: Largest accepted vertical (and depth) camera offset, as a share of the horizontal baseline term.
MAX_VERTICAL_SHARE = 0.05


def _fmt(v):
    return f"{v:.10g}"


def as_matrix(value, rows, cols, key):
    """``value`` as a finite float64 ``rows x cols`` array, or :class:`RiverbedError` naming ``key``.

    Accepts nested lists of numbers (and of numeric strings: YAML 1.1 reads ``1e-3`` as a string).
    """
    what = f"a {rows}x{cols} matrix" if rows > 1 else f"{cols} numbers"
    seq = value if rows > 1 else [value]
    if not isinstance(seq, (list, tuple, np.ndarray)) or len(seq) != rows:
        got = f"{len(seq)} rows" if isinstance(seq, (list, tuple, np.ndarray)) else type(value).__name__
        raise RiverbedError(f"{key}: expected {what}, got {got}")
    out = np.empty((rows, cols), np.float64)
    for i, row in enumerate(seq):
        if not isinstance(row, (list, tuple, np.ndarray)) or len(row) != cols:
            got = f"{len(row)} numbers" if isinstance(row, (list, tuple, np.ndarray)) else type(row).__name__
            where = f"row {i + 1} has" if rows > 1 else "got"
            raise RiverbedError(f"{key}: expected {what}, {where} {got}")
        for j, v in enumerate(row):
            x = parse_number(v)
            if x is None:
                raise RiverbedError(f"{key}: entry {_where(i, j, rows)} is not a number: {v!r}")
            if not math.isfinite(x):
                raise RiverbedError(f"{key}: entry {_where(i, j, rows)} is not finite: {v!r}")
            out[i, j] = x
    return out if rows > 1 else out[0]


def _where(i, j, rows):
    return f"[{i}][{j}]" if rows > 1 else f"[{j}]"


_NUMBER = re.compile(r"\s*[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?\s*|\s*[-+]?(inf|nan)\s*", re.IGNORECASE)


def parse_number(v):
    """``v`` as a float when it is a number or a numeric string (``inf``, ``nan`` too); None otherwise, bools too."""
    if isinstance(v, bool):
        return None
    if isinstance(v, (int, float, np.integer, np.floating)):
        return float(v)
    if isinstance(v, str) and _NUMBER.fullmatch(v):
        return float(v)
    return None


def check_rectified(P_left, P_right):
    """Check that two 3 x 4 matrices form a rectified pair; return ``(s, t, v, u)``.

    ``s``: constant horizontal image shift (``x_R = x_L + s + ...``), ``t``: the baseline term of the 4th
    column, ``v``, ``u``: the 4th-column differences in rows 1 and 2 (0 for an exactly rectified pair). Raises
    :class:`RiverbedError` naming the entries that break the rule. Indices in messages are 0-based
    ``[row][col]``.
    """
    ML, MR = P_left[:, :3], P_right[:, :3]
    scale = float(np.abs(ML).max())
    tol = RECTIFIED_RTOL * scale
    bad = [(i, j) for i in (1, 2) for j in range(3) if abs(MR[i, j] - ML[i, j]) > tol]
    m3 = ML[2]
    delta = MR[0] - ML[0]
    s = float(delta @ m3 / (m3 @ m3))
    resid = delta - s * m3
    bad += [(0, j) for j in range(3) if abs(resid[j]) > tol]
    if bad:
        bad.sort()
        shown = ", ".join(f"[{i}][{j}] ({_fmt(P_left[i, j])} vs {_fmt(P_right[i, j])})" for i, j in bad)
        raise RiverbedError(
            f"P_left and P_right are not a rectified pair: they differ at {shown}; a rectified pair differs "
            "only by a horizontal shift (equal rows 1 and 2, row 0 may add a multiple of row 2, 4th column "
            "free)"
        )
    t = float(P_right[0, 3] - P_left[0, 3] - s * P_left[2, 3])
    v = float(P_right[1, 3] - P_left[1, 3])
    u = float(P_right[2, 3] - P_left[2, 3])
    if abs(t) <= tol:
        raise RiverbedError("P_left and P_right have the same camera centre (no baseline)")
    # The right camera must be to the right: d = -s - t / w > -s in front (w has the sign of det M).
    if t * np.sign(np.linalg.det(ML)) > 0:
        raise RiverbedError(
            "P_right is to the left of P_left (disparities would be negative): swap left and right")
    # Offsets of the right camera off the baseline: rows shift by about (v - y u) / w against x by t / w.
    x0 = ML @ m3
    span = 2.0 * max(abs(x0[0] / x0[2]), abs(x0[1] / x0[2]), 1.0)  # ~ image size from the principal point
    share = (abs(v) + abs(u) * span) / abs(t)
    if share > MAX_VERTICAL_SHARE:
        raise RiverbedError(
            f"P_left and P_right are not a rectified pair: the right camera is off the baseline (4th column "
            f"[1][3] {_fmt(P_left[1, 3])} vs {_fmt(P_right[1, 3])}, [2][3] {_fmt(P_left[2, 3])} vs "
            f"{_fmt(P_right[2, 3])}): {100 * share:.1f} % of the horizontal shift, above "
            f"{100 * MAX_VERTICAL_SHARE:.0f} %"
        )
    return s, t, v, u


def check_range(value):
    """A disparity range ``[lo, hi]`` (px) as a tuple of two floats; :class:`RiverbedError` for anything else."""
    try:
        lo, hi = (float(v) for v in value)
    except (TypeError, ValueError):
        raise RiverbedError(f"disparity: expected [low, high] in pixels, got {value!r}") from None
    if not (math.isfinite(lo) and math.isfinite(hi)) or lo > hi:
        raise RiverbedError(f"disparity: expected finite [low, high] with low <= high, got {value!r}")
    return lo, hi


@dataclass(frozen=True, eq=False)
class PairGeometry:
    """A rectified stereo pair: cameras, world origin, LiDAR registration, CRS, image paths and size.

    Attributes
    ----------
    P_left, P_right : (3, 4) float64
        Projection matrices of the rectified cameras, world minus origin -> pixels.
    origin : (3,) float64
        Subtracted from world coordinates before projection (default 0).
    registration : (4, 4) float64
        LiDAR -> world transform (default identity); invertible, last row ``0 0 0 1``.
    crs : str or None
        CRS of world coordinates (any string pyproj or rasterio understands, e.g. ``EPSG:32632``).
    left, right : Path or None
        The rectified images (absolute once loaded from a pair file).
    width, height : int or None
        Image size in pixels, if known.
    disparity : (lo, hi) or None
        The pair's disparity range (px, ``d = x_left - x_right``), if known: what ``riverbed rectify`` found (tie
        points) and ``riverbed match --pair`` searches.
    """

    P_left: np.ndarray
    P_right: np.ndarray
    origin: np.ndarray = field(default_factory=lambda: np.zeros(3))
    registration: np.ndarray = field(default_factory=lambda: np.eye(4))
    crs: str | None = None
    left: Path | None = None
    right: Path | None = None
    width: int | None = None
    height: int | None = None
    disparity: tuple | None = None

    def __post_init__(self):
        set_ = object.__setattr__.__get__(self)
        set_("P_left", as_matrix(self.P_left, 3, 4, "P_left"))
        set_("P_right", as_matrix(self.P_right, 3, 4, "P_right"))
        set_("origin", as_matrix(self.origin, 1, 3, "origin"))
        reg = as_matrix(self.registration, 4, 4, "registration")
        check_registration(reg)
        set_("registration", reg)
        for key in ("P_left", "P_right"):
            M = getattr(self, key)[:, :3]
            if abs(np.linalg.det(M)) <= 1e-12 * float(np.abs(M).max()) ** 3:
                raise RiverbedError(f"{key}: the left 3x3 block is singular (not a finite camera)")
        s, t, v, u = check_rectified(self.P_left, self.P_right)
        set_("_shift", (s, t, v, u))
        for key in ("width", "height"):
            val = getattr(self, key)
            if val is not None:
                integer = isinstance(val, (int, np.integer)) and not isinstance(val, bool)
                if not integer or not 0 < val <= 10_000_000:
                    raise RiverbedError(f"{key}: expected a positive integer (pixels), got {val!r}")
                set_(key, int(val))
        if self.crs is not None and not isinstance(self.crs, str):
            raise RiverbedError(f"crs: expected a string such as EPSG:32632, got {type(self.crs).__name__}")
        for key in ("left", "right"):
            val = getattr(self, key)
            if val is not None:
                set_(key, Path(val))
        if self.disparity is not None:
            set_("disparity", check_range(self.disparity))

    # -- derived quantities ------------------------------------------------------------------------------
    @property
    def exactly_rectified(self):
        """True when the right camera lies exactly on the horizontal baseline (no row offset at any depth)."""
        _, _, v, u = self._shift
        return v == 0.0 and u == 0.0

    @property
    def centres(self):
        """Camera centres ``(C_left, C_right)`` in world-minus-origin coordinates."""
        return tuple(-np.linalg.solve(P[:, :3], P[:, 3]) for P in (self.P_left, self.P_right))

    @property
    def baseline(self):
        """Distance between the camera centres, in world units."""
        cl, cr = self.centres
        return float(np.linalg.norm(cr - cl))

    @property
    def focal(self):
        """Horizontal focal length of the left camera in pixels (``|m1 x m3| / |m3|^2``, zero skew)."""
        M = self.P_left[:, :3]
        return float(np.linalg.norm(np.cross(M[0], M[2])) / (M[2] @ M[2]))

    @property
    def image_size(self):
        """``(height, width)`` if both are known, else None."""
        if self.width is None or self.height is None:
            return None
        return self.height, self.width

    def replace(self, **changes):
        """A copy with some fields changed (validated again)."""
        fields = {k: getattr(self, k) for k in ("P_left", "P_right", "origin", "registration", "crs", "left",
                                                  "right", "width", "height", "disparity")}
        fields.update(changes)
        return PairGeometry(**fields)

    # -- coordinates -------------------------------------------------------------------------------------
    def lidar_to_local(self, xyz, registration=None):
        """LiDAR coordinates (N, 3) -> world minus origin (float64): ``registration @ p - origin``."""
        R = self.registration if registration is None else registration
        xyz = np.asarray(xyz, np.float64)
        return xyz @ R[:3, :3].T + (R[:3, 3] - self.origin)

    def _depth_scale(self, P):
        M = P[:, :3]
        return float(np.sign(np.linalg.det(M)) / np.linalg.norm(M[2]))

    def project(self, xyz, full=False):
        """Project world-minus-origin points (N, 3) into both images, in float64.

        Returns
        -------
        x_left, y_left, x_right, depth : (N,) float64
            Pixel coordinates (centres at integers) and the depth along the left optical axis (world units,
            positive in front). Points with depth <= 0 give meaningless pixel coordinates.
        With ``full=True`` also ``y_right`` and ``depth_right`` (depth along the right optical axis).
        """
        xyz = np.asarray(xyz, np.float64)
        x, y, z = xyz[:, 0], xyz[:, 1], xyz[:, 2]
        out = []
        for P in (self.P_left, self.P_right):
            # Element-wise rather than a (N, 3) @ (3, 3) product: no BLAS threads, the same sum order as the
            # projection kernel.
            u, v, w = (P[i, 0] * x + P[i, 1] * y + P[i, 2] * z + P[i, 3] for i in range(3))
            with np.errstate(divide="ignore", invalid="ignore"):
                out.append((u / w, v / w, w * self._depth_scale(P)))
        (xl, yl, zl), (xr, yr, zr) = out
        if full:
            return xl, yl, xr, zl, yr, zr
        return xl, yl, xr, zl

    def triangulate(self, x_left, y_left, d):
        """World-minus-origin points (N, 3) projecting to ``(x_left, y_left)`` with disparity ``d``.

        The exact inverse of :meth:`project` (``x_right = x_left - d``; the right row is not used, so it also
        holds for a pair whose right camera is slightly off the baseline). Add ``origin`` for world
        coordinates.
        """
        x = np.asarray(x_left, np.float64).ravel()
        y = np.asarray(y_left, np.float64).ravel()
        xr = x - np.asarray(d, np.float64).ravel()
        PL, PR = self.P_left, self.P_right
        rows = [PL[0][None, :] - x[:, None] * PL[2][None, :],
                PL[1][None, :] - y[:, None] * PL[2][None, :],
                PR[0][None, :] - xr[:, None] * PR[2][None, :]]
        A = np.stack(rows, axis=1)  # (N, 3, 4): A @ [X, 1] = 0
        with np.errstate(all="ignore"):
            return np.linalg.solve(A[:, :, :3], -A[:, :, 3:])[:, :, 0]


def check_registration(reg, key="registration"):
    """A 4 x 4 LiDAR -> world transform must end in ``0 0 0 1`` and be invertible."""
    if np.abs(reg[3] - np.array([0.0, 0.0, 0.0, 1.0])).max() > 1e-12:
        raise RiverbedError(f"{key}: the last row must be 0 0 0 1, got {' '.join(_fmt(v) for v in reg[3])}")
    block = reg[:3, :3]
    if abs(np.linalg.det(block)) <= 1e-12 * max(float(np.abs(block).max()), 1e-300) ** 3:
        raise RiverbedError(f"{key}: the 3x3 block is singular (not an invertible transform)")


# -- importers -------------------------------------------------------------------------------------------
def _middlebury_matrix(text, key, path):
    m = re.fullmatch(r"\[(.*)\]", text.strip())
    if not m:
        raise RiverbedError(f"{key}: expected [f 0 cx; 0 f cy; 0 0 1], got {text.strip()[:60]!r}", path)
    rows = [r.split() for r in m.group(1).split(";")]
    try:
        return as_matrix(rows, 3, 3, key)
    except RiverbedError as e:
        raise RiverbedError(str(e), path) from None


def middlebury_pair(calib_path, scale=1.0, left=None, right=None):
    """A :class:`PairGeometry` from a Middlebury 2014 ``calib.txt``.

    The left camera frame is the world (origin 0, identity registration), in **metres**: ``baseline`` (mm in
    the file) is divided by 1000, so LiDAR-like clouds in metres project directly. ``scale`` is the image size
    factor (0.5 for half size, 0.25 for quarter size): pixel quantities (f, cx, cy, doffs, width, height)
    scale, world units do not. Principal points follow the pixel-centre convention
    ``c' = (c + 0.5) * scale - 0.5``. ``doffs`` appears as the difference of the two principal points
    (``cam1 cx - cam0 cx``), which the file must agree with.
    """
    path = Path(calib_path)
    text = _read_text(path)
    values = {}
    for line in text.splitlines():
        if "=" in line:
            k, v = line.split("=", 1)
            values[k.strip()] = v.strip()
    for key in ("cam0", "cam1", "baseline"):
        if key not in values:
            raise RiverbedError(f"not a Middlebury calib.txt: no '{key}=' line", path)
    if not (math.isfinite(scale) and scale > 0):
        raise RiverbedError(f"scale must be a positive number, got {scale}")
    K0 = _middlebury_matrix(values["cam0"], "cam0", path)
    K1 = _middlebury_matrix(values["cam1"], "cam1", path)
    for key, K in (("cam0", K0), ("cam1", K1)):
        if K[0, 1] != 0 or K[1, 0] != 0 or K[2, 0] != 0 or K[2, 1] != 0 or K[2, 2] != 1 or K[0, 0] <= 0:
            raise RiverbedError(f"{key}: expected [f 0 cx; 0 f cy; 0 0 1] with f > 0", path)
    if K0[0, 0] != K1[0, 0] or K0[1, 1] != K1[1, 1] or K0[1, 2] != K1[1, 2]:
        raise RiverbedError("cam0 and cam1 differ in focal length or cy: not a rectified pair", path)
    numbers = {}
    for key in ("baseline", "doffs", "width", "height"):
        if key in values:
            x = parse_number(values[key])
            if x is None or not math.isfinite(x):
                raise RiverbedError(f"{key}: not a number: {values[key]!r}", path)
            numbers[key] = x
    if numbers["baseline"] <= 0:
        raise RiverbedError(f"baseline: must be positive (mm), got {values['baseline']}", path)
    if "doffs" in numbers:
        doffs, shift = numbers["doffs"], K1[0, 2] - K0[0, 2]
        if abs(shift - doffs) > 1e-3 * max(1.0, abs(doffs)):
            raise RiverbedError(f"doffs {_fmt(doffs)} disagrees with cam1 cx - cam0 cx = {_fmt(shift)}", path)

    def scaled(K):
        K = K.copy()
        K[0, 0] *= scale
        K[1, 1] *= scale
        K[0, 2] = (K[0, 2] + 0.5) * scale - 0.5
        K[1, 2] = (K[1, 2] + 0.5) * scale - 0.5
        return K

    K0, K1 = scaled(K0), scaled(K1)
    b = numbers["baseline"] / 1000.0
    P_left = np.hstack([K0, np.zeros((3, 1))])
    P_right = np.hstack([K1, K1 @ np.array([[-b], [0.0], [0.0]])])
    size = {}
    for key in ("width", "height"):
        if key in numbers:
            size[key] = round(numbers[key] * scale)
    return PairGeometry(P_left, P_right, left=left, right=right, **size)


def _read_text(path, limit=1_000_000):
    if not path.exists():
        raise RiverbedError("file not found", path)
    if not path.is_file():
        raise RiverbedError("not a file", path)
    if path.stat().st_size > limit:
        raise RiverbedError(f"too large for a calibration file ({path.stat().st_size} bytes)", path)
    try:
        return path.read_bytes().decode("utf-8")
    except UnicodeDecodeError:
        raise RiverbedError("not a text file", path) from None


def kitti_pair(calib_path, left=None, right=None, width=None, height=None):
    """A :class:`PairGeometry` from a KITTI object-benchmark calibration file.

    ``P_left``/``P_right`` are ``P2``/``P3`` as given (the colour cameras, projecting from the rectified
    camera-0 frame, which is the world: origin 0, in metres). The registration maps Velodyne to that frame:
    ``R0_rect @ Tr_velo_to_cam`` (both padded to 4 x 4). KITTI's P2 and P3 also differ in the 4th column's
    entries [1][3] and [2][3] (0.216 vs 2.20 px·m, 2.746e-3 vs 2.730e-3 m): camera 3 sits 2.7 mm below the
    baseline of camera 2, which shifts the right image's rows by about 2.0 px·m / depth (0.5 px at 4 m, 0.84
    px at the nearest KITTI point, 2.4 m); see :func:`check_rectified`.
    """
    path = Path(calib_path)
    text = _read_text(path)
    values = {}
    for line in text.splitlines():
        if ":" in line:
            k, v = line.split(":", 1)
            values[k.strip()] = v.split()
    need = {"P2": 12, "P3": 12, "R0_rect": 9, "Tr_velo_to_cam": 12}
    mats = {}
    for key, n in need.items():
        if key not in values:
            raise RiverbedError(f"not a KITTI object calibration: no '{key}:' line", path)
        if len(values[key]) != n:
            raise RiverbedError(f"{key}: expected {n} numbers, got {len(values[key])}", path)
        try:
            flat = as_matrix(values[key], 1, n, key)
        except RiverbedError as e:
            raise RiverbedError(str(e), path) from None
        mats[key] = flat
    R0 = np.eye(4)
    R0[:3, :3] = mats["R0_rect"].reshape(3, 3)
    Tr = np.eye(4)
    Tr[:3, :] = mats["Tr_velo_to_cam"].reshape(3, 4)
    try:
        return PairGeometry(mats["P2"].reshape(3, 4), mats["P3"].reshape(3, 4), registration=R0 @ Tr,
                            left=left, right=right, width=width, height=height)
    except RiverbedError as e:
        raise RiverbedError(str(e), path) from None
