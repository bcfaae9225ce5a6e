"""Compare a disparity map with ground truth.

Middlebury-style bad-pixel rates, mean absolute error, RMSE, density and KITTI D1.

Conventions: arrays ``H x W`` indexed ``[row, col]``, disparity ``d = x_left - x_right`` in pixels, NaN marks
an invalid prediction or a pixel without ground truth.
"""

import numpy as np

from ..errors import RiverbedError

#: The metric names, in the order :func:`evaluate_disparity` returns them.
METRICS = ("bad1", "bad2", "bad3", "avg", "rmse", "density", "d1", "n")


def _shape(a):
    return "x".join(str(n) for n in np.shape(a))


def evaluation_mask(gt, exclude=None, max_disp=None):
    """Pixels that take part in the evaluation.

    Parameters
    ----------
    gt : array_like, ``H x W``
        Ground-truth disparity in pixels, NaN where unknown (0 is a valid disparity here; readers turn the
        formats' "unknown" markers into NaN).
    exclude : array_like, ``H x W``, optional
        Pixels to leave out, typically the sparse LiDAR disparities used as guidance: a disparity map (its
        finite pixels are excluded) or a boolean mask (True = excluded).
    max_disp : float, optional
        Leave out ground truth above this disparity (e.g. beyond the search range).

    Returns
    -------
    mask : ndarray of bool, ``H x W``
        True where ``gt`` is finite, ``gt <= max_disp`` (if given) and the pixel is not excluded.
    """
    gt = np.asarray(gt, dtype=np.float64)
    mask = np.isfinite(gt)
    if max_disp is not None:
        mask &= gt <= float(max_disp)
    if exclude is not None:
        exclude = np.asarray(exclude)
        if exclude.shape != gt.shape:
            raise RiverbedError(
                f"exclusion map and ground truth differ in shape: {_shape(exclude)} vs {_shape(gt)}"
            )
        mask &= ~exclude if exclude.dtype == bool else ~np.isfinite(exclude)
    return mask


def evaluate_disparity(disp, gt, exclude=None, max_disp=None):
    """Accuracy of a disparity map against ground truth.

    Parameters
    ----------
    disp : array_like, ``H x W``
        Predicted disparity in pixels, NaN (any non-finite value) where the matcher gave none.
    gt : array_like, ``H x W``
        Ground-truth disparity in pixels, NaN where unknown.
    exclude, max_disp
        Restrict the evaluated pixels, see :func:`evaluation_mask`.

    Returns
    -------
    metrics : dict
        In this order, over the ``n`` evaluated pixels, with ``e = |disp - gt|``:

        - ``bad1``, ``bad2``, ``bad3`` (%): share with no valid prediction or ``e > 1``, ``> 2``, ``> 3`` px.
        - ``avg`` (px): mean ``e`` over the pixels with a valid prediction (the paper's eq. 7); NaN if none.
        - ``rmse`` (px): root mean square of ``e`` over the same pixels; NaN if none.
        - ``density`` (%): share with a valid prediction.
        - ``d1`` (%): KITTI D1, share with no valid prediction or ``e > 3 px`` and ``e > 5 % of |gt|``.
        - ``n`` (int): number of evaluated pixels.

        Invalid predictions count as errors in ``bad*`` and ``d1`` but are left out of ``avg`` and ``rmse``
        (``density`` reports how many there were). Values are Python floats (``n`` an int).

    Raises
    ------
    RiverbedError
        Shapes differ, or no pixel is left to evaluate.
    """
    disp = np.asarray(disp, dtype=np.float64)
    gt = np.asarray(gt, dtype=np.float64)
    if disp.shape != gt.shape:
        raise RiverbedError(f"disparity and ground truth differ in shape: {_shape(disp)} vs {_shape(gt)}")
    if disp.ndim != 2:
        raise RiverbedError(f"disparity must be a 2-D array (H x W), got shape {_shape(disp)}")
    mask = evaluation_mask(gt, exclude, max_disp)
    n = int(mask.sum())
    if n == 0:
        raise RiverbedError(
            "no ground-truth pixels to evaluate (ground truth all unknown, excluded or above --max-disp)"
        )
    d, g = disp[mask], gt[mask]
    valid = np.isfinite(d)
    # float64 throughout so thresholds like e > 1 are not blurred by float32 rounding.
    err = np.abs(d - g)  # NaN where invalid; comparisons with NaN are False, hence the explicit ~valid
    n_valid = int(valid.sum())

    def percent(bad):
        return float(100.0 * np.count_nonzero(bad) / n)

    e = err[valid]
    return {
        "bad1": percent(~valid | (err > 1)),
        "bad2": percent(~valid | (err > 2)),
        "bad3": percent(~valid | (err > 3)),
        "avg": float(e.mean()) if n_valid else float("nan"),
        "rmse": float(np.sqrt(np.mean(e * e))) if n_valid else float("nan"),
        "density": float(100.0 * n_valid / n),
        "d1": percent(~valid | ((err > 3) & (err > 0.05 * np.abs(g)))),
        "n": n,
    }
