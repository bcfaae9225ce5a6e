"""Simulated LiDAR for benchmarks: a seeded random share of ground-truth pixels (the paper's protocol)."""

import numpy as np

from ..errors import RiverbedError


def simulate_lidar(gt, share, seed=0):
    """Sample ``share`` of the image's pixels from the valid ground truth, as sparse LiDAR disparities.

    Parameters
    ----------
    gt : (H, W) float
        Ground-truth disparity, NaN where unknown.
    share : float
        Fraction of *all* pixels ``H * W`` to sample (e.g. 0.05, 0.0123, 0.0016), drawn among the GT pixels.
    seed : int
        Seed of ``numpy.random.default_rng``: the same seed gives the same points.

    Returns
    -------
    (H, W) float32
        The sampled disparities, NaN elsewhere. Evaluate on the other GT pixels (``evaluate --exclude``).
    """
    gt = np.asarray(gt, dtype=np.float32)
    if not 0 < share <= 1:
        raise RiverbedError(f"LiDAR share must be in (0, 1], got {share}")
    valid = np.flatnonzero(np.isfinite(gt))
    if valid.size == 0:
        raise RiverbedError("ground truth has no valid pixels to sample")
    n = min(valid.size, max(1, int(round(share * gt.size))))
    idx = np.random.default_rng(seed).choice(valid, n, replace=False)
    sparse = np.full(gt.shape, np.nan, dtype=np.float32)
    sparse.flat[idx] = gt.flat[idx]
    return sparse
