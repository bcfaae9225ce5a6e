"""Typed results of matching: :class:`MatchResult` and its :class:`MatchInfo`.

``MatchInfo`` reads like the dict it replaces (``result.info["seconds"]``, ``{**result.info}``) and
:meth:`MatchInfo.to_dict` gives the ``--json`` keys of ``riverbed match``.
"""

from dataclasses import dataclass, field

import numpy as np

from ..records import RecordMapping


@dataclass
class MatchInfo(RecordMapping):
    """What a match did: timings (s), the settings that mattered, the range searched.

    ``stages`` holds seconds per stage (``cost``, ``guidance``, ``aggregation``, ``refinement``: the SGM
    matcher's ``aggregation`` includes the disparity selection, which runs in the same kernel; AD-Census's
    ``selection`` and ``optimisation``; ``first_pass`` for riverbed+); ``window`` the riverbed window used (None for
    guides without one); ``size`` ``[width, height]``; ``refinement`` AD-Census's outlier counts and timings;
    ``range`` the search-range mode (``tube`` or ``full``); ``tubes`` with tubes: ``mean_width``, ``max_width``,
    ``nominal`` (disparities of ``[d_min, d_max]``) and ``full_share`` (share of pixels searching the nominal
    range); ``lidar_offset`` with LiDAR, its disparity offset against the images (:mod:`.lidar_offset`);
    ``lidar_check`` with LiDAR, what the check dropped (:class:`~riverbed_cli.matching.lidar_check.CheckReport`).
    """

    seconds: float
    stages: dict
    guide: str
    matcher: str
    lidar_share: float
    lidar_points: int
    window: int = None
    d_min: int = 0
    d_max: int = 0
    size: list = field(default_factory=list)
    refinement: dict = None
    range: str = "full"
    tubes: dict = None
    fusion: str = "none"
    fusion_stats: dict = None
    lidar_offset: dict = None
    outside_overlap: float = 0.0
    lidar_check: dict = None

    _optional = ("refinement", "tubes", "fusion_stats", "lidar_offset", "lidar_check")


@dataclass
class TiledMatchInfo(RecordMapping):
    """What a tiled match did (:func:`~riverbed_cli.scale.tiles.match_tiled`): :class:`MatchInfo`'s keys that
    hold for the whole image, plus ``tiles`` (count), ``tile`` (px), ``overlap`` (px), ``disparity_evaluations``
    (sum over tiles of crop pixels x disparities: the work done) and ``tile_ranges`` (tiles whose range came from
    their LiDAR, their neighbours, or the global range); with tubes ``range`` is ``tube`` and ``tubes`` the whole
    image's tube statistics over the tiles' own pixels (as :class:`MatchInfo`'s)."""

    seconds: float
    stages: dict
    guide: str
    lidar_share: float
    window: int
    d_min: int
    d_max: int
    size: list
    tiles: int
    tile: int
    overlap: int
    disparity_evaluations: int
    tile_ranges: dict
    range: str = "tile"
    tubes: dict = None
    lidar_offset: dict = None
    lidar_check: dict = None

    _optional = ("tubes", "lidar_offset", "lidar_check")


@dataclass
class MatchResult:
    """A dense disparity map (``(H, W)`` float32, NaN invalid, ``d = x_left - x_right``), its info, and with a
    fusion the per-pixel ``confidence`` ((H, W) float32 in [0, 1]: the estimated probability of an error below 1 px;
    :mod:`~riverbed_cli.matching.fusion`) and with the LiDAR check its ``lidar_check``
    (:class:`~riverbed_cli.matching.lidar_check.LidarCheck`: what it dropped, the changed area)."""

    disparity: np.ndarray
    info: RecordMapping
    confidence: np.ndarray = None
    lidar_check: object = None
