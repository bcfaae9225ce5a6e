"""``riverbed``: the paper's guidance, Gauss at the LiDAR pixels and band-and-walls at their homogeneous pixels
(:func:`..guidance.riverbed_modulate`)."""

from .. import guidance
from ..registry import register_guide
from .base import Guidance, Guide


def riverbed_window(share, config):
    """The riverbed window: ``config.guidance.window``, or for ``"auto"`` the rule of :func:`..guidance.auto_window`."""
    g = config.guidance
    return guidance.auto_window(share, g.window_target) if g.window == "auto" else int(g.window)


@register_guide
class Riverbed(Guide):
    name = "riverbed"
    needs_image = True
    uses_window = True

    def window(self, share, config):
        return riverbed_window(share, config)

    def modulate(self, volume, inputs, config):
        g = config.guidance
        window = self.window(inputs.share, config)
        points = inputs.lidar()
        owners = guidance.homogeneous_owners(inputs.sparse, inputs.image, window, g.sigma_xy, g.sigma_i, g.gamma,
                                             g.literal_eq3, points)
        data = guidance.riverbed_modulate(volume.data, inputs.sparse, inputs.image, volume.d_min, window, g.k, g.c,
                                          g.sigma_xy, g.sigma_i, g.gamma, g.band, g.form, volume.scale, inputs.max_cost,
                                          owners=owners, inplace=True, literal_eq3=g.literal_eq3,
                                          wall_scale=inputs.wall_scale, tubes=volume.tubes, points=points)
        support = None
        if inputs.want_support:  # riverbed+ and AD-Census's guided stages (their modules load here: start-up)
            from ..riverbed_plus import riverbed_support

            support = riverbed_support(inputs.sparse, owners, g.band)
        return Guidance(volume.like(data, inputs.max_cost), window, support)
