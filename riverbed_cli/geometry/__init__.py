"""Camera geometry of a rectified pair: projection matrices, LiDAR projection, visibility, outlier removal.

Conventions (as everywhere in riverbed): pixel centres at integer coordinates, arrays indexed ``[row, col]``,
the left image is the reference and ``d = x_left - x_right``. World coordinates are float64 and have the
pair's ``origin`` subtracted before anything else touches them.

The names below load on first use (``lazy_loader``): importing :mod:`.cameras` does not load the projection's
kernels.
"""

import lazy_loader

__getattr__, __dir__, __all__ = lazy_loader.attach(
    __name__,
    submod_attrs={"cameras": ["PairGeometry", "kitti_pair", "middlebury_pair"], "projection": ["project_cloud"]},
)
