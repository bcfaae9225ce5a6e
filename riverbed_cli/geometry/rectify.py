"""Rectify two aerial frames from their interior and exterior orientation (``riverbed rectify``).

Two raw (unrectified) frame images and their orientation files become a rectified pair: ``left.png``,
``right.png`` and the pair file ``pair.yaml`` whose cameras are the exact cameras of the written images.

The orientation files and their conventions (photogrammetric rotation, OpenCV camera axes, distortion,
world coordinates) are in :mod:`riverbed_cli.geometry.orientation`; its names are importable from here too.

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
from pyproj import CRS

from ..errors import RiverbedError
from ..io.atomic import atomic_output, check_output_folder
from ..io.images import MAX_PIXELS, read_image, write_png_file
from .pairfile import write_pairfile
from .tie_points import rectification_check, warn_on_parallax
from .cameras import PairGeometry
from .frame_range import range_from_clouds, range_from_heights
from .orientation import (
    FrameOrientation,
    load_orientation,
    matrix_to_opk,
    opk_to_matrix,
    orientation_dict,
    orientation_from_dict,
    write_orientation,
)

__all__ = [
    "FrameOrientation", "INTERPOLATION", "OUTPUTS", "Rectified", "check_alpha", "load_orientation",
    "matrix_to_opk", "opk_to_matrix", "orientation_dict", "orientation_from_dict", "parse_size", "rectify",
    "rectify_files", "write_orientation",
]

log = logging.getLogger(__name__)

#: ``cv2.remap`` interpolation of the rectified images.
INTERPOLATION = cv2.INTER_CUBIC
_ZERO_DISPARITY = getattr(cv2, "STEREO_ZERO_DISPARITY", getattr(cv2, "CALIB_ZERO_DISPARITY", 1024))


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
    ``valid_areas[i]``: (H, W) bool, the rectified pixels inside raw image ``i`` (None: all of them), written as the
    PNGs' alpha channel.
    """

    left: np.ndarray
    right: np.ndarray
    pair: PairGeometry
    maps: tuple
    rotations: tuple
    K: tuple
    info: dict
    valid_areas: tuple = (None, None)


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

    rotations, maps, images, valid, areas = [], [], [], [], []
    for o, K, img in ((left, K1, left_image), (right, K2, right_image)):
        Rr = R_fin @ o.R.T  # raw camera axes -> rectified camera axes
        mx, my = cv2.initUndistortRectifyMap(o.K, o.dist, Rr, K, out_size, cv2.CV_32FC1)
        images.append(cv2.remap(img, mx, my, interpolation, borderMode=cv2.BORDER_CONSTANT, borderValue=0))
        inside = (mx >= -0.5) & (mx <= W - 0.5) & (my >= -0.5) & (my <= H - 0.5)
        valid.append(round(float(inside.mean()), 6))
        areas.append(None if inside.all() else inside)
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
    return Rectified(images[0], images[1], pair, tuple(maps), tuple(rotations), (K1, K2), info, tuple(areas))


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
                  alpha=0.0, size=None, max_pixels=None, heights=None, dem=None, lidar=(), lidar_crs=None):
    """Read two raw frames and their orientation files, rectify, write left.png, right.png, pair.yaml.

    ``outdir`` is created if missing (its parent must exist). All three outputs are written under temporary
    names and renamed into place only once all are complete; existing outputs are replaced only with
    ``overwrite``. Returns a summary dict (files and sizes, focal length, baseline, rotation, valid shares, and the
    tie points' check of the written pair, :func:`~riverbed_cli.geometry.tie_points.rectification_check`: its
    vertical parallax, with a warning above 1 px, and the disparities it shows).

    The pair file's disparity range (``disparity``, what ``riverbed match --pair`` searches) comes from
    ``heights`` (``(lo, hi)`` m), from a ``dem`` or ``lidar`` clouds (LAS/LAZ; ``lidar_crs`` their CRS when the
    files state none) or, with none of them, from the tie points (:mod:`~riverbed_cli.geometry.frame_range`); the
    summary's ``disparity`` and ``disparity_from`` say which.
    """
    clouds = [*([dem] if dem else []), *(lidar or ())]
    if sum(bool(v) for v in (dem, heights is not None, lidar)) > 1:
        raise RiverbedError("give the terrain by one of --heights LO,HI, --dem DEM or --lidar CLOUD (or none: the "
                            "range from tie points)")
    t0 = time.perf_counter()
    outdir = Path(outdir)
    check_output_folder(outdir, OUTPUTS, overwrite,
                        inputs=[left_image, left_orientation, right_image, right_orientation])
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
    # the rectification checked on the rectified images: tie points' rows, and the disparities they show (the
    # pair file's range, which riverbed match --pair searches)
    check = rectification_check(result.left, result.right, valid_areas=result.valid_areas)
    shape = result.left.shape[:2]
    if heights is not None:
        rng, source = range_from_heights(result.pair, heights, shape), f"--heights {heights[0]:g},{heights[1]:g}"
    elif clouds:
        *rng, n = range_from_clouds(result.pair, clouds, shape, lidar_crs)
        source = f"{', '.join(Path(c).name for c in clouds)} ({n} points seen by both images)"
    else:
        rng, source = check.get("disparity"), f"{check['tie_points']} tie points"
    outdir.mkdir(exist_ok=True)
    paths = [outdir / name for name in OUTPUTS]
    pair = result.pair.replace(left=paths[0].absolute(), right=paths[1].absolute(), disparity=rng)
    info = result.info
    names = [Path(p).name for p in (left_image, left_orientation, right_image, right_orientation)]
    found = (f"disparity range {rng[0]}..{rng[1]} px from {source} (riverbed match --pair searches it)"
             if rng is not None else f"no disparity range: {source}")
    comment = (f"Rectified by riverbed rectify from {names[0]} ({names[1]}) and {names[2]} ({names[3]}).\n"
               f"f = {info['focal_px']:.6f} px, baseline {info['baseline']:.6f}: d = x_left - x_right = "
               f"{info['fB']:.6f} / depth (px); images turned by {info['turn_deg'][0]} (left) and "
               f"{info['turn_deg'][1]} deg (right); {found}.")
    with atomic_output(paths[0], overwrite) as t_left, atomic_output(paths[1], overwrite) as t_right, \
            atomic_output(paths[2], overwrite) as t_pair:
        write_png_file(t_left, result.left, valid=result.valid_areas[0])
        write_png_file(t_right, result.right, valid=result.valid_areas[1])
        write_pairfile(t_pair, pair, comment=comment)
    files = {name: p.stat().st_size for name, p in zip(OUTPUTS, paths)}
    warn_on_parallax(check, str(outdir))
    return {"outdir": str(outdir), "files": files, **info, "tie_points": check,
            "disparity": None if rng is None else [int(v) for v in rng], "disparity_from": source,
            "seconds": round(time.perf_counter() - t0, 3)}
