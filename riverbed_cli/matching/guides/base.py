"""The interface of a guide: what it needs, how it modulates a cost volume, what support it vouches for."""

from dataclasses import dataclass

import numpy as np

from ...geometry.coverage import lidar_points
from ..volume import CostVolume


@dataclass
class GuidanceInputs:
    """What a matcher hands a guide.

    ``sparse``: (H, W) float32 LiDAR disparities of the left image, NaN elsewhere (all inside the searched range);
    ``image``: the left image on a 0..255 scale, (H, W, C) float32 (:func:`~riverbed_cli.io.images.to_guide`) or
    uint8 as read (:func:`~riverbed_cli.io.images.guide_source`), or None for guides that do not read it;
    ``share``: the LiDAR share of the image (:func:`~riverbed_cli.matching.guidance.lidar_share`); ``wall_scale``: the
    wall scale ``F_bar`` in plain cost units;
    ``max_cost``: the largest guided cost the aggregation can take (stored units); ``first_pass``: what the guide's
    :meth:`Guide.prepare` returned; ``want_support``: also return the support (AD-Census's refinement keeps the
    winners inside it); ``points``: the LiDAR's ``(rows, cols, values)``
    (:func:`~riverbed_cli.geometry.coverage.lidar_points` of ``sparse``), or None (:meth:`lidar` finds them).
    """

    sparse: np.ndarray
    image: np.ndarray
    share: float
    wall_scale: float
    max_cost: int
    first_pass: object = None
    want_support: bool = False
    points: tuple = None

    def lidar(self):
        """``(rows, cols, values)`` of the LiDAR pixels of ``sparse``, found once (``match_pair`` passes them; a
        search of the image took 0.5-0.7 ms a time on 740 x 500 px)."""
        if self.points is None:
            self.points = lidar_points(self.sparse)
        return self.points


@dataclass
class Guidance:
    """A guide's output: the modulated volume (its ``max_cost`` the guide's), the riverbed window used (None
    for guides without one) and the support, a per-pixel ``(lo, hi)`` disparity interval the guide vouches for
    (NaN where it vouches for nothing), or None."""

    volume: CostVolume
    window: int = None
    support: tuple = None


class Guide:
    """A cost-volume guide. Subclasses set ``name`` and ``help`` and implement :meth:`modulate`.

    Attributes
    ----------
    needs_sparse : bool
        The guide reads LiDAR disparities (every guide but ``none``).
    needs_image : bool
        :meth:`modulate` reads ``inputs.image`` (colour similarities).
    uses_window : bool
        The guide uses the riverbed window: tiles fix it once for the whole image (:meth:`window`).
    has_first_pass : bool
        :meth:`prepare` runs a first matching pass (timed as the ``first_pass`` stage).
    """

    name = ""
    needs_sparse = True
    needs_image = False
    uses_window = False
    has_first_pass = False

    def window(self, share, config):
        """The riverbed window side for a LiDAR share (None for guides without one)."""
        return None

    def prepare(self, left, right, sparse, d_min, d_max, config, matcher, tubes=None):
        """Work before matching (riverbed+'s first pass); its result reaches :meth:`modulate` as
        ``inputs.first_pass``. Default: nothing."""
        return None

    def modulate(self, volume, inputs, config):
        """Modulate ``volume`` (a :class:`CostVolume`, uint16, may be changed in place); returns :class:`Guidance`."""
        raise NotImplementedError
