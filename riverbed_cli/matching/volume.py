"""``CostVolume``: the matching cost and what it takes to read it, as it travels from stage to stage."""

from dataclasses import dataclass

import numpy as np


@dataclass
class CostVolume:
    """A cost volume with its metadata.

    Attributes
    ----------
    data : (H, W, D) uint8 or uint16
        Costs of the left image's pixels; index ``i`` holds disparity ``d = d_min + i`` (``d = x_left - x_right``,
        px). Lower is better.
    d_min : int
        Disparity of index 0. (Per-pixel search ranges will add an ``(H, W)`` offset to it: index ``i`` of pixel
        ``(y, x)`` then holds ``d_min + offset[y, x] + i``.)
    scale : int
        Stored units per plain cost unit (census: Hamming units; AD-Census: 1.0 of the paper's cost). Penalties of
        the aggregation must be multiplied by it.
    max_cost : int
        The largest value ``data`` may hold (stored units): bounds the aggregation's sums.
    """

    data: np.ndarray
    d_min: int
    scale: int
    max_cost: int

    @property
    def n_disp(self):
        """Number of disparities ``D``."""
        return int(self.data.shape[2])

    @property
    def d_max(self):
        """Largest disparity held (inclusive)."""
        return self.d_min + self.n_disp - 1
