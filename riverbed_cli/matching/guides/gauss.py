"""``gauss``: Gauss enhancement at the LiDAR pixels (Poggi et al. 2019; :func:`..guidance.gauss_modulate`)."""

from .. import guidance
from ..registry import register_guide
from .base import Guidance, Guide


@register_guide
class Gauss(Guide):
    name = "gauss"

    def modulate(self, volume, inputs, config):
        g = config.guidance
        data = guidance.gauss_modulate(volume.data, inputs.sparse, volume.d_min, g.k, g.c, g.form, volume.scale,
                                       inputs.max_cost, inplace=True, wall_scale=inputs.wall_scale, tubes=volume.tubes,
                                       points=inputs.lidar())
        # the LiDAR pixels vouch for their own disparity
        support = (inputs.sparse, inputs.sparse) if inputs.want_support else None
        return Guidance(volume.like(data, inputs.max_cost), None, support)
