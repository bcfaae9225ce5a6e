"""Epipolar rectification of an RPC pair over a region of interest: the s2p way (``docs/rpc.md``).

Over a small region the projection of a pushbroom pair is nearly affine, so its epipolar geometry is that of two
affine cameras (Hartley & Zisserman, ch. 14): an *affine fundamental matrix* and two *similarities* that turn the
(parallel) epipolar lines of both images into the same image rows. As s2p (de Franchis et al. 2014,
``s2p/rectification.py``: ``rpc_utils.matches_from_rpc`` -> ``estimation.affine_fundamental_matrix`` ->
``estimation.rectifying_similarities_from_affine_fundamental_matrix`` -> ``register_horizontally_shear``):

1. **Virtual matches**: a grid of points over the left ROI, each localised at several heights over the height
   range and projected into the right image (:meth:`RPCModel.localize`, :meth:`RPCModel.project`).
2. **Affine fundamental matrix** ``F = [[0, 0, a], [0, 0, b], [c, d, e]]`` (``a x2 + b y2 + c x1 + d y1 + e =
   0``) by total least squares on the centred matches (the Gold Standard algorithm, H&Z algorithm 14.1).
3. **Rectifying similarities**: rotate the left image so that ``(c, d)`` points down its rows, the right so that
   ``-(a, b)`` does, the right also scaled by ``|(a, b)| / |(c, d)|``: then ``y1' = y2'`` for every match.
4. **Horizontal registration**: a shear, scale and shift of the right image's columns (rows untouched), fitted on
   the matches at the middle height, so that disparities are small and nearly constant on the mean terrain;
   both images turned by 180 degrees if needed so that disparity grows with height, and the right image shifted
   so that ``d = x_left - x_right >= 0`` over the height range (riverbed's convention).

Images are resampled with ``cv2.warpAffine`` (bicubic, 0 outside). Coordinates: pixel centres at integers,
``(0, 0)`` the centre of each image file's first pixel (``rpc.py``).
"""

from dataclasses import dataclass, field

import cv2
import numpy as np

from ..errors import RiverbedError


@dataclass
class RPCRectification:
    """The two rectifying affinities (3 x 3, image pixel -> rectified pixel) and what they were fitted on.

    ``H_left``, ``H_right`` map a pixel of the left / right image file to the rectified left / right image;
    ``size`` is (width, height) of both rectified images; ``disparity`` the (min, max) of ``d = x_left -
    x_right`` over the height range, margin included; ``heights`` the (lo, hi) range (m, ellipsoidal).
    """

    H_left: np.ndarray
    H_right: np.ndarray
    size: tuple
    disparity: tuple
    heights: tuple
    roi: tuple
    info: dict = field(default_factory=dict)

    def to_dict(self):
        return {"H_left": self.H_left.tolist(), "H_right": self.H_right.tolist(), "width": int(self.size[0]),
                "height": int(self.size[1]), "disparity": [float(v) for v in self.disparity],
                "heights": [float(v) for v in self.heights], "roi": [int(v) for v in self.roi], **self.info}


def apply_h(H, x, y):
    """``H`` (3 x 3 affine or homography) applied to pixel coordinates ``x, y`` (arrays)."""
    x = np.asarray(x, np.float64)
    y = np.asarray(y, np.float64)
    w = H[2, 0] * x + H[2, 1] * y + H[2, 2]
    return (H[0, 0] * x + H[0, 1] * y + H[0, 2]) / w, (H[1, 0] * x + H[1, 1] * y + H[1, 2]) / w


def virtual_matches(rpc_left, rpc_right, roi, heights, n=11, n_heights=5):
    """Left ROI grid points localised at ``n_heights`` heights in ``heights`` and projected into the right image.

    Returns ``(x1, y1, x2, y2, h)``, flat float64 arrays (px, px, px, px, m).
    """
    x, y, w, h = roi
    gx, gy, gh = np.meshgrid(np.linspace(x, x + w - 1, n), np.linspace(y, y + h - 1, n),
                             np.linspace(heights[0], heights[1], n_heights), indexing="ij")
    gx, gy, gh = gx.ravel(), gy.ravel(), gh.ravel()
    lon, lat = rpc_left.localize(gx, gy, gh)
    x2, y2 = rpc_right.project(lon, lat, gh)
    ok = np.isfinite(x2) & np.isfinite(y2)
    return gx[ok], gy[ok], x2[ok], y2[ok], gh[ok]


def affine_fundamental_matrix(x1, y1, x2, y2):
    """The affine fundamental matrix of matches by total least squares (H&Z algorithm 14.1).

    ``F = [[0, 0, a], [0, 0, b], [c, d, e]]`` with ``[x2, y2, 1] F [x1, y1, 1]^T = a x2 + b y2 + c x1 + d y1 + e``
    minimal in the least-squares sense, ``a^2 + b^2 + c^2 + d^2 = 1``.
    """
    X = np.column_stack([x2, y2, x1, y1])
    mean = X.mean(axis=0)
    _, _, vt = np.linalg.svd(X - mean, full_matrices=False)
    a, b, c, d = vt[-1]
    e = -vt[-1] @ mean
    return np.array([[0, 0, a], [0, 0, b], [c, d, e]], dtype=np.float64)


def rectifying_similarities(F):
    """Similarities ``(S_left, S_right)`` (3 x 3) that map the epipolar lines of ``F`` onto common rows.

    ``y1' = (c x1 + d y1 + e) / n`` and ``y2' = -(a x2 + b y2) / n`` with ``n = |(c, d)|``: equal for every pair
    on the epipolar constraint. Each x axis is the rotation's other row (determinant > 0: no mirror).
    """
    a, b = F[0, 2], F[1, 2]
    c, d, e = F[2, 0], F[2, 1], F[2, 2]
    n = np.hypot(c, d)
    S1 = np.array([[d / n, -c / n, 0.0], [c / n, d / n, e / n], [0, 0, 1]])
    S2 = np.array([[-b / n, a / n, 0.0], [-a / n, -b / n, 0.0], [0, 0, 1]])
    return S1, S2


def rectify_rpc_pair(rpc_left, rpc_right, roi, heights, n=11, n_heights=5, margin_px=5.0):
    """The s2p-style affine rectification of an RPC pair over ``roi`` of the left image and a height range.

    Parameters
    ----------
    rpc_left, rpc_right : RPCModel
        Models in the pixel frames of the two image files.
    roi : (x, y, w, h)
        Region of the left image (px); the rectified left image covers it.
    heights : (lo, hi)
        Ellipsoidal height range of the terrain over the ROI (m).
    n, n_heights : int
        Virtual match grid: ``n x n`` points times ``n_heights`` heights.
    margin_px : float
        Added to both ends of the disparity range.

    Returns
    -------
    RPCRectification
    """
    lo, hi = float(heights[0]), float(heights[1])
    if not hi > lo:
        hi = lo + 1.0
    x1, y1, x2, y2, hh = virtual_matches(rpc_left, rpc_right, roi, (lo, hi), n, n_heights)
    if x1.size < 8:
        raise RiverbedError("the two RPC models do not see the ROI in common (no virtual match)")
    F = affine_fundamental_matrix(x1, y1, x2, y2)
    S1, S2 = rectifying_similarities(F)
    u1, v1 = apply_h(S1, x1, y1)
    u2, v2 = apply_h(S2, x2, y2)
    # horizontal registration on the middle height: u1 ~ s u2 + t v2 + k (rows unchanged)
    mid = np.isclose(hh, np.median(np.unique(hh)))
    A = np.column_stack([u2[mid], v2[mid], np.ones(mid.sum())])
    s, t, k = np.linalg.lstsq(A, u1[mid], rcond=None)[0]
    R = np.array([[s, t, k], [0, 1, 0], [0, 0, 1]])
    H1, H2 = S1, R @ S2
    u2, v2 = apply_h(H2, x2, y2)
    d = u1 - u2
    slope = np.polyfit(hh, d, 1)[0]
    if slope < 0:                               # disparity must grow with height: turn both by 180 degrees
        turn = np.diag([-1.0, -1.0, 1.0])
        H1, H2 = turn @ H1, turn @ H2
        u1, v1 = apply_h(H1, x1, y1)
        u2, v2 = apply_h(H2, x2, y2)
        d = u1 - u2
    # the left ROI's bounding box in rectified coordinates becomes the output frame
    x, y, w, h = roi
    cx = np.array([x, x + w - 1, x, x + w - 1], np.float64)
    cy = np.array([y, y, y + h - 1, y + h - 1], np.float64)
    ru, rv = apply_h(H1, cx, cy)
    u0, v0 = np.floor(ru.min()), np.floor(rv.min())
    width, height = int(np.ceil(ru.max() - u0)) + 1, int(np.ceil(rv.max() - v0)) + 1
    dmin = float(d.min()) - margin_px
    T1 = np.array([[1, 0, -u0], [0, 1, -v0], [0, 0, 1]], np.float64)
    T2 = np.array([[1, 0, -u0 + dmin], [0, 1, -v0], [0, 0, 1]], np.float64)
    H1, H2 = T1 @ H1, T2 @ H2
    u1, v1 = apply_h(H1, x1, y1)
    u2, v2 = apply_h(H2, x2, y2)
    d = u1 - u2
    info = {"virtual_matches": int(x1.size),
            "virtual_row_residual_max_px": float(np.max(np.abs(v1 - v2))),
            "virtual_row_residual_rms_px": float(np.sqrt(np.mean((v1 - v2) ** 2))),
            "disparity_per_metre": float(np.polyfit(hh, d, 1)[0])}
    return RPCRectification(H_left=H1, H_right=H2, size=(width, height),
                            disparity=(0.0, float(d.max()) + margin_px), heights=(lo, hi),
                            roi=tuple(int(v) for v in roi), info=info)


def resample(image, H, size, interpolation=cv2.INTER_CUBIC):
    """``image`` (H, W) or (H, W, C) resampled into the rectified frame of affinity ``H``; 0 outside, same dtype."""
    if not np.allclose(H[2], [0, 0, 1]):
        raise ValueError("resample takes an affinity")
    img = np.ascontiguousarray(image)
    if img.dtype not in (np.uint8, np.uint16, np.int16, np.float32, np.float64):
        img = img.astype(np.float32)
    return cv2.warpAffine(img, H[:2], (int(size[0]), int(size[1])), flags=interpolation,
                          borderMode=cv2.BORDER_CONSTANT, borderValue=0)


def heights_over_roi(rpc, roi, dem, margin_m=20.0, n=21):
    """The (lo, hi) ellipsoidal height range (m) of the DEM under the left ROI, widened by ``margin_m``.

    The ROI is localised on the DEM on an ``n x n`` grid (:meth:`RPCModel.localize_dem`), then the DEM's extremes
    over that footprint's bounding box are taken; a footprint the DEM does not cover is a :class:`RiverbedError`.
    """
    x, y, w, h = roi
    gx, gy = np.meshgrid(np.linspace(x, x + w - 1, n), np.linspace(y, y + h - 1, n))
    lon, lat, hh = rpc.localize_dem(gx, gy, dem)
    if np.isnan(hh).any():
        raise RiverbedError("the DEM does not cover the ROI's footprint", dem.source)
    box = dem.height(*np.meshgrid(np.linspace(lon.min(), lon.max(), 4 * n), np.linspace(lat.min(), lat.max(), 4 * n)))
    lo, hi = np.nanmin([box.min(), hh.min()]), np.nanmax([box.max(), hh.max()])
    return float(lo - margin_m), float(hi + margin_m)


def stretch_to_uint8(image):
    """An image scaled to 8 bits between its 0.5 and 99.5 percentiles of non-zero values (for feature detectors)."""
    img = np.asarray(image, np.float64)
    if img.ndim == 3:
        img = img.mean(axis=2)
    valid = img > 0
    lo, hi = np.percentile(img[valid], [0.5, 99.5]) if valid.any() else (0.0, 1.0)
    return np.clip((img - lo) * 255.0 / max(hi - lo, 1e-9), 0, 255).astype(np.uint8)


def estimate_row_offset(rect_left, rect_right, disparity, ratio=0.75):
    """The relative pointing error of an RPC pair as a row offset of the rectified right image (px).

    RPCs carry a pointing error of a few pixels (Pléiades: ~5 px on the Ventoux pair), the same over a small ROI:
    s2p corrects it as a translation of the second image fitted on tie points (``pointing_accuracy.py``). Here the
    tie points are OpenCV ORB matches (not SIFT: the benchmark measures with SIFT) between the two rectified
    images (Lowe's ratio test), refined by Lucas-Kanade, kept where their
    disparity lies in ``disparity`` +- 10 px; the offset is the median of ``y_left - y_right``. Returns ``(offset,
    n_matches)``; a :class:`RiverbedError` when fewer than 10 matches survive.
    """
    a, b = stretch_to_uint8(rect_left), stretch_to_uint8(rect_right)
    orb = cv2.ORB_create(nfeatures=5000)
    ka, da = orb.detectAndCompute(a, (np.asarray(rect_left) > 0).astype(np.uint8))
    kb, db = orb.detectAndCompute(b, (np.asarray(rect_right) > 0).astype(np.uint8))
    if da is None or db is None or len(ka) < 10 or len(kb) < 10:
        raise RiverbedError("too few features in the rectified images to estimate the RPC pointing error")
    pairs = cv2.BFMatcher(cv2.NORM_HAMMING).knnMatch(da, db, k=2)
    good = [m for m, m2 in (p for p in pairs if len(p) == 2) if m.distance < ratio * m2.distance]
    pa = np.array([ka[m.queryIdx].pt for m in good]).reshape(-1, 2)
    pb = np.array([kb[m.trainIdx].pt for m in good]).reshape(-1, 2)
    if len(pa):
        # ORB's keypoints are coarse: refine the right positions by Lucas-Kanade (21 px window, no pyramid)
        pb2, st, _ = cv2.calcOpticalFlowPyrLK(a, b, pa.astype(np.float32).reshape(-1, 1, 2),
                                              pb.astype(np.float32).reshape(-1, 1, 2).copy(), winSize=(21, 21),
                                              maxLevel=0, flags=cv2.OPTFLOW_USE_INITIAL_FLOW)
        pb2 = pb2.reshape(-1, 2).astype(np.float64)
        keep = (st.ravel() == 1) & (np.abs(pb2 - pb).max(axis=1) < 2.0)
        pa, pb = pa[keep], pb2[keep]
    d = pa[:, 0] - pb[:, 0]
    dy = pa[:, 1] - pb[:, 1]
    ok = (d >= disparity[0] - 10) & (d <= disparity[1] + 10) & (np.abs(dy) < 20)
    if ok.sum() < 10:
        raise RiverbedError(f"too few tie points ({int(ok.sum())}) to estimate the RPC pointing error")
    dy = dy[ok]
    med = np.median(dy)
    dy = dy[np.abs(dy - med) < 2.0]                  # a second pass without the gross outliers
    return float(np.median(dy)), int(dy.size)


def with_row_offset(rect, offset):
    """``rect`` with the right image moved by ``offset`` rows (``y_right += offset``): the pointing correction."""
    T = np.array([[1, 0, 0], [0, 1, offset], [0, 0, 1]], np.float64)
    info = {**rect.info, "pointing_row_offset_px": float(offset)}
    return RPCRectification(H_left=rect.H_left, H_right=T @ rect.H_right, size=rect.size,
                            disparity=rect.disparity, heights=rect.heights, roi=rect.roi, info=info)
