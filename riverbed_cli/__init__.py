"""riverbed: LiDAR-guided stereo matching (riverbed enhancement), as plain functions over numpy arrays.

Conventions: the left image is the reference; disparity ``d = x_left - x_right`` (px); invalid = NaN; arrays are
indexed ``[row, col]``; cost volumes are ``H x W x D`` with disparity innermost.

The names below load on first use (scientific-python's ``lazy_loader``), so ``import riverbed_cli`` and
``riverbed --help`` load no Numba kernel.
"""

import os

import lazy_loader

# Numba's OpenMP workers sleep between parallel regions instead of spinning (unless the user chose otherwise): the
# fusion's LiDAR side runs in a thread beside the matcher (matching/pipeline.py), and spinning workers took its core
# (the default fused match 16 % slower than sleeping ones, docs/tubes.md). Read when the OpenMP library loads, at
# the first parallel kernel, so it is set here, before any.
# riverbed's own default is marked, so that a riverbed process started by another (a benchmark, a test, a dask
# worker), which inherits it, tells it from a user's choice
_OMP_MARK = "RIVERBED_OMP_DEFAULT"
#: the user chose how OpenMP workers wait (then riverbed leaves it alone: scale/workers.py)
OMP_WAIT_FROM_USER = "GOMP_SPINCOUNT" in os.environ or (
    "OMP_WAIT_POLICY" in os.environ and os.environ["OMP_WAIT_POLICY"] != os.environ.get(_OMP_MARK))
if "OMP_WAIT_POLICY" not in os.environ:
    os.environ["OMP_WAIT_POLICY"] = os.environ[_OMP_MARK] = "PASSIVE"

__getattr__, __dir__, __all__ = lazy_loader.attach(
    __name__,
    submod_attrs={
        "errors": ["RiverbedError"],
        "io.disparity": ["read_disparity", "write_disparity"],
        "io.images": ["read_image", "to_grey", "to_guide"],
        "matching.census": ["census_cost", "census_transform"],
        "matching.disparity": ["median_filter", "select_disparity"],
        "matching.guidance": ["auto_window", "gauss_modulate", "homogeneous_owners", "lidar_share",
                              "riverbed_modulate"],
        "matching.config": ["MatchConfig", "MATCH_SETTINGS"],
        "matching.pipeline": ["match_pair"],
        "matching.results": ["MatchInfo", "MatchResult"],
        "matching.registry": ["MATCHERS", "GUIDES"],
        "matching.volume": ["CostVolume"],
        "matching.sgm": ["sgm_aggregate"],
        "geometry.cameras": ["PairGeometry"],
        "geometry.projection": ["project_cloud"],
        "geometry.pairfile": ["load_pairfile", "write_pairfile"],
        "products.dsm": ["build_dsm", "rasterize"],
        "products.dsm_compare": ["compare_dsm"],
        "products.evaluate": ["evaluate_disparity"],
        "products.simulate": ["simulate_lidar"],
        "scale.tiles": ["match_tiled"],
    },
)
