"""Camera geometry of a rectified pair: projection matrices, LiDAR projection, visibility, outlier removal.

Conventions (as everywhere in riverbed): pixel centres at integer coordinates, arrays indexed ``[row, col]``,
the left image is the reference and ``d = x_left - x_right``. World coordinates are float64 and have the
pair's ``origin`` subtracted before anything else touches them.
"""

from .cameras import PairGeometry, kitti_pair, middlebury_pair
from .projection import project_cloud

__all__ = ["PairGeometry", "kitti_pair", "middlebury_pair", "project_cloud"]
