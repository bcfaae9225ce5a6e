"""The interface of a matcher: a rectified pair and a guide in, a dense disparity map out."""

from dataclasses import dataclass

import numpy as np


@dataclass
class MatcherOutput:
    """A matcher's result: ``disparity`` (H, W) float32, NaN invalid; ``window`` the riverbed window its guide
    used (or None); ``refinement`` a matcher's own report (AD-Census's outlier counts) or None; ``status`` the
    left-right outcome per pixel when asked for (``return_status``: 0 consistent, > 0 failing; AD-Census: 1
    mismatch, 2 occlusion)."""

    disparity: np.ndarray
    window: int = None
    refinement: dict = None
    status: np.ndarray = None


class Matcher:
    """A stereo matcher. Subclasses set ``name`` and implement :meth:`match` and :meth:`unreliable`."""

    name = ""
    supports_tubes = False  # match() takes per-pixel tubes (tubes=(offset, width))
    #: Tiles of a tube match are sized for the tubes' volume (``scale.match_plan.auto_tile``'s 6 bytes per tube cost:
    #: SGM's three uint16 volumes); False sizes them for the nominal volume, as a full-range match.
    tube_sized_tiles = False

    def match(self, left, right, sparse, d_min, d_max, config, guide, share, first_pass, stages, tubes=None,
              return_status=False, points=None):
        """Match a rectified pair (left image the reference) over ``[d_min, d_max]``.

        ``sparse`` is checked and inside the range (or None for ``guide`` ``none``), ``share`` its LiDAR share,
        ``first_pass`` what ``guide.prepare`` returned; ``stages`` is filled with seconds per stage; ``tubes``, for
        matchers with ``supports_tubes``, a :class:`~riverbed_cli.matching.volume.TubeLayout` (per-pixel ranges).
        With ``return_status`` the output's ``status`` holds the left-right check per pixel (the fusion's stereo
        confidence). ``points``: ``lidar_points(sparse)`` if the caller has them (the guide then does not look for
        them again). Returns a :class:`MatcherOutput`.
        """
        raise NotImplementedError

    def unreliable(self, left, right, sparse, d_min, d_max, config, lr_threshold, tubes=None):
        """(H, W) bool: pixels whose match with ``config`` (riverbed-guided) fails the left-right check."""
        raise NotImplementedError
