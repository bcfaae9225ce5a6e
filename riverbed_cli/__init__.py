"""riverbed: LiDAR-guided stereo matching (riverbed enhancement), as plain functions over numpy arrays.

Conventions: the left image is the reference; disparity ``d = x_left - x_right`` (px); invalid = NaN; arrays are
indexed ``[row, col]``; cost volumes are ``H x W x D`` with disparity innermost.
"""

from .errors import RiverbedError
from .io.disparity import read_disparity, write_disparity
from .io.images import read_image, to_grey, to_guide
from .matching.census import census_cost, census_transform
from .matching.disparity import median_filter, select_disparity
from .matching.guidance import (
    auto_window,
    gauss_modulate,
    homogeneous_owners,
    lidar_share,
    riverbed_modulate,
)
from .matching.pipeline import MatchParams, MatchResult, match_pair
from .matching.sgm import sgm_aggregate
from .geometry.cameras import PairGeometry
from .geometry.projection import project_cloud
from .io.pairfile import load_pairfile, write_pairfile
from .products.dsm import build_dsm, rasterize
from .products.dsm_compare import compare_dsm
from .products.evaluate import evaluate_disparity
from .products.simulate import simulate_lidar
from .scale.tiles import match_tiled

__all__ = [
    "RiverbedError", "read_disparity", "write_disparity", "read_image", "to_grey", "to_guide", "census_cost",
    "census_transform", "median_filter", "select_disparity", "auto_window", "gauss_modulate", "homogeneous_owners",
    "lidar_share", "riverbed_modulate", "MatchParams", "MatchResult", "match_pair", "sgm_aggregate",
    "evaluate_disparity", "simulate_lidar", "PairGeometry", "project_cloud", "load_pairfile", "write_pairfile",
    "build_dsm", "rasterize", "compare_dsm", "match_tiled",
]
