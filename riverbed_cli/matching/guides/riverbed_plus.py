"""``riverbed+``: riverbed, extended through cross-based support regions to the pixels a first pass could not match
(:mod:`..riverbed_plus`)."""

import numpy as np

from ...errors import RiverbedError
from ..config import CONFIDENCES
from ..registry import register_guide
from .base import Guidance, Guide
from .riverbed import riverbed_window


@register_guide
class RiverbedPlus(Guide):
    name = "riverbed+"
    needs_image = True
    uses_window = True
    has_first_pass = True

    def window(self, share, config):
        return riverbed_window(share, config)

    def prepare(self, left, right, sparse, d_min, d_max, config, matcher, tubes=None):
        """The first pass: pixels whose riverbed-guided match fails the left-right check (None: extend to all)."""
        q = config.plus
        if q.confidence == "none":
            return None
        if q.confidence not in CONFIDENCES:
            raise RiverbedError(f"unknown riverbed+ confidence '{q.confidence}' (use lr or none)")
        mask = matcher.unreliable(left, right, sparse, d_min, d_max, config.replace(guide="riverbed"),
                                  q.lr_threshold, tubes)
        return np.asarray(mask, dtype=bool)

    def modulate(self, volume, inputs, config):
        from ..riverbed_plus import riverbed_plus_modulate  # loaded by the runs that use it (start-up)

        g = config.guidance
        window = self.window(inputs.share, config)
        data, extra = riverbed_plus_modulate(volume.data, inputs.sparse, inputs.image, volume.d_min, window, g.k, g.c,
                                             g.sigma_xy, g.sigma_i, g.gamma, g.band, g.form, volume.scale,
                                             inputs.max_cost, inputs.wall_scale, config.plus, inputs.first_pass,
                                             inputs.share, inplace=True, return_support=inputs.want_support,
                                             tubes=volume.tubes)
        return Guidance(volume.like(data, inputs.max_cost), window, extra.get("support"))
