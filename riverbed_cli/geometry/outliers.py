"""Statistical outlier removal (SOR) for LiDAR points that land in the image.

For each point, the mean distance to its ``k`` nearest neighbours, divided by the point's depth from the camera
(an angular spacing: a terrestrial scanner's spacing grows with range, which plain SOR would read as outliers;
for an aerial view the depth is nearly constant and this is the classic SOR). A point is an outlier when that
value exceeds ``median + n_sigma * 1.4826 * MAD`` of all points (a robust mean + n sigma: the outliers themselves
do not inflate the threshold).

The points are the candidates kept per pixel (at most two per pixel, see
:func:`riverbed_cli.geometry.projection.project_cloud`), so memory is bounded by the image size whatever the
size of the cloud, and neighbours come from every chunk of the file. Points outside the image are not
neighbours: near the image border a point has fewer close neighbours, which the robust threshold tolerates.
"""

import numpy as np

SOR_K = 8
SOR_SIGMA = 5.0


def sor_inliers(xyz, depth, k=SOR_K, n_sigma=SOR_SIGMA):
    """Boolean mask of the points of ``xyz`` (N, 3) that are not statistical outliers.

    Parameters
    ----------
    xyz : (N, 3) float64
        Points in a metric frame (world minus origin).
    depth : (N,) float64
        Depth of each point from the camera (> 0), to turn distances into angular spacing.
    k : int
        Neighbours per point.
    n_sigma : float
        Threshold in robust standard deviations above the median.
    """
    from scipy.spatial import cKDTree

    xyz = np.asarray(xyz, np.float64)
    n = xyz.shape[0]
    if n <= k + 1:
        return np.ones(n, bool)
    tree = cKDTree(xyz)
    dist, _ = tree.query(xyz, k=k + 1, workers=-1)
    spacing = dist[:, 1:].mean(axis=1) / np.maximum(np.asarray(depth, np.float64), 1e-12)
    med = float(np.median(spacing))
    mad = float(np.median(np.abs(spacing - med))) * 1.4826
    if mad == 0:
        mad = max(float(spacing.std()), 1e-12)
    return spacing <= med + n_sigma * mad
