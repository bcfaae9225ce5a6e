"""Tie points of a rectified pair: the check that rectification worked, and the disparity range the images show.

A correctly rectified pair has every scene point on the same row of both images. Tie points matched between the two
rectified images measure that: their row differences ``dy`` (the vertical parallax) are a few tenths of a pixel
when the orientations are right, and pixels to hundreds of pixels when a rotation is transposed, an angle convention
is another one, or a frame is mismatched. Their column differences are disparities ``d = x_left - x_right``: the
range the images themselves show, without LiDAR or a DEM (as s2p does).

Matching: ORB features (OpenCV) in both images, Hamming nearest neighbours kept by Lowe's ratio test and by mutual
agreement, then RANSAC on the fundamental matrix (a rectified pair's is known only when the rectification is right,
so the check cannot assume it). ORB's positions are whole pixels: each kept match is refined to sub-pixel by pyramidal
Lucas-Kanade from the left position to the right one (OpenCV), and dropped when the refinement fails or moves it by
more than 2 px.
"""

import logging

import cv2
import numpy as np
from scipy.spatial import cKDTree

log = logging.getLogger(__name__)

#: Features detected per image.
FEATURES = 4000
#: Lowe's ratio (nearest / second-nearest Hamming distance).
RATIO = 0.8
#: Fewest tie points for a verdict.
MIN_POINTS = 12
#: Median |dy| (px) above which rectify warns: the orientations or their convention are likely wrong.
WARN_PX = 1.0
#: A tie point's disparity must lie within this many px of the median of its nearest neighbours' (repeated texture
#: gives matches on the right row but the wrong column, isolated among their neighbours).
NEIGHBOURS, AGREE_PX = 16, 16.0
#: Share of the agreeing tie points left out at each end of the range (a cluster of wrong matches on repeated texture)
TRIM = 0.005
#: The range's margin: px, and share of its span.
RANGE_MARGIN, RANGE_GROWTH = 4, 0.50


def _grey8(img):
    img = np.asarray(img)
    if img.ndim == 3:
        img = cv2.cvtColor(img[:, :, :3], cv2.COLOR_RGB2GRAY)
    if img.dtype != np.uint8:
        top = float(np.percentile(img, 99.5)) or 1.0
        img = np.clip(img.astype(np.float32) * (255.0 / top), 0, 255).astype(np.uint8)
    return np.ascontiguousarray(img)


def tie_points(left, right, *, valid_areas=(None, None), features=FEATURES):
    """Sub-pixel tie points of two images (rectified or not).

    Parameters
    ----------
    left, right : (H, W) or (H, W, 3) uint8 / uint16 arrays
    valid_areas : (left_valid, right_valid)
        Where each image shows the scene ((H, W) bool or None): features are looked for there only.
    features : int
        ORB features per image.

    Returns
    -------
    (n, 2) float64 left positions (x, y), (n, 2) float64 right positions (x, y); pixel centres at integers.
    """
    a, b = _grey8(left), _grey8(right)
    orb = cv2.ORB_create(nfeatures=int(features), fastThreshold=10)
    masks = [None if v is None else np.asarray(v, np.uint8) * 255 for v in valid_areas]
    ka, da = orb.detectAndCompute(a, masks[0])
    kb, db = orb.detectAndCompute(b, masks[1])
    empty = np.empty((0, 2)), np.empty((0, 2))
    if da is None or db is None or len(ka) < 2 or len(kb) < 2:
        return empty
    bf = cv2.BFMatcher(cv2.NORM_HAMMING)
    ab = bf.knnMatch(da, db, k=2)
    ba = {m[0].queryIdx: m[0].trainIdx for m in bf.knnMatch(db, da, k=2) if m}
    pairs = [m[0] for m in ab if len(m) == 2 and m[0].distance < RATIO * m[1].distance
             and ba.get(m[0].trainIdx) == m[0].queryIdx]
    if len(pairs) < 8:
        return empty
    pa = np.float32([ka[m.queryIdx].pt for m in pairs])
    pb = np.float32([kb[m.trainIdx].pt for m in pairs])
    _, inliers = cv2.findFundamentalMat(pa, pb, cv2.FM_RANSAC, 1.5, 0.999)
    if inliers is None:
        return empty
    keep = inliers.ravel().astype(bool)
    pa, pb = pa[keep], pb[keep]
    # sub-pixel: Lucas-Kanade from each left position, starting at its ORB match in the right image
    refined, status, _ = cv2.calcOpticalFlowPyrLK(a, b, pa.reshape(-1, 1, 2), pb.reshape(-1, 1, 2).copy(),
                                                  winSize=(15, 15), maxLevel=1,
                                                  flags=cv2.OPTFLOW_USE_INITIAL_FLOW)
    refined = refined.reshape(-1, 2)
    ok = status.ravel().astype(bool) & (np.hypot(*(refined - pb).T) <= 2.0)
    return pa[ok].astype(np.float64), refined[ok].astype(np.float64)


def rectification_check(left, right, *, valid_areas=(None, None)):
    """The vertical parallax and the disparity range of a rectified pair, from its tie points (module docstring).

    Returns a dict: ``tie_points`` (count), ``dy_median_px`` (median |y_left - y_right|), ``dy_p90_px``,
    ``dy_mean_px`` (signed: a shift of one image), and ``disparity`` (``[lo, hi]`` px: the span of the tie points
    whose disparity agrees with their neighbours' (:func:`agreeing`), :data:`TRIM` of them left out at each end,
    widened by :data:`RANGE_MARGIN` px and :data:`RANGE_GROWTH` of the span), or only ``tie_points`` when there are
    fewer than :data:`MIN_POINTS`.
    """
    pl, pr = tie_points(left, right, valid_areas=valid_areas)
    out = {"tie_points": int(len(pl))}
    if len(pl) < MIN_POINTS:
        return out
    dy = pl[:, 1] - pr[:, 1]
    d = pl[:, 0] - pr[:, 0]
    out.update({"dy_median_px": round(float(np.median(np.abs(dy))), 3),
                "dy_p90_px": round(float(np.quantile(np.abs(dy), 0.9)), 3),
                "dy_mean_px": round(float(np.mean(dy)), 3)})
    agree = agreeing(pl, d)
    if agree.sum() >= MIN_POINTS:
        lo, hi = (float(v) for v in np.quantile(d[agree], [TRIM, 1.0 - TRIM]))
        grow = RANGE_MARGIN + RANGE_GROWTH * (hi - lo)
        out["disparity"] = [int(np.floor(lo - grow)), int(np.ceil(hi + grow))]
    return out


def agreeing(points, d, k=NEIGHBOURS, tol=AGREE_PX):
    """Tie points whose disparity ``d`` lies within ``tol`` px of the median of their ``k`` nearest neighbours'."""
    k = min(int(k), len(d) - 1)
    _, idx = cKDTree(points).query(points, k=k + 1)
    return np.abs(d - np.median(d[idx[:, 1:]], axis=1)) <= tol


def warn_on_parallax(check, what="rectified pair"):
    """Log the one-line warning of a rectification whose tie points disagree in rows by more than :data:`WARN_PX`
    (median), or that has too few of them to tell; returns True when it warned."""
    if check["tie_points"] < MIN_POINTS:
        log.warning("%s: only %d tie points matched: the rectified images show too little texture, or not the same "
                    "scene on their rows (the orientations or their convention likely wrong)", what,
                    check["tie_points"])
        return True
    if check["dy_median_px"] > WARN_PX:
        log.warning("%s: the tie points' rows differ by %.2f px (median of %d): the orientations, or the convention "
                    "they were converted with (a rotation transposed, another angle order), are likely wrong",
                    what, check["dy_median_px"], check["tie_points"])
        return True
    return False
