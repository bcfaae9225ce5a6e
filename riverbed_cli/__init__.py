"""riverbed: LiDAR-guided stereo matching (riverbed enhancement), as plain functions over numpy arrays.

Conventions: the left image is the reference; disparity ``d = x_left - x_right`` (px); invalid = NaN; arrays are
indexed ``[row, col]``; cost volumes are ``H x W x D`` with disparity innermost.

The names below load on first use (scientific-python's ``lazy_loader``), so ``import riverbed_cli`` and
``riverbed --help`` load no Numba kernel. Importing riverbed changes no environment variable and no process setting;
the settings the ``riverbed`` program runs with are :class:`riverbed_cli.runtime.Env`'s, an opt-in for programs.
"""

import lazy_loader

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
