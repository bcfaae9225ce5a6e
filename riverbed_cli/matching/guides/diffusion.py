"""``diffusion``: Shivakumar et al. 2019's diffusion-based fusion (:func:`..diffusion.diffusion_modulate`)."""

from dataclasses import asdict

from ..registry import register_guide
from .base import Guidance, Guide


@register_guide
class Diffusion(Guide):
    name = "diffusion"
    needs_image = True

    def modulate(self, volume, inputs, config):
        from ..diffusion import diffusion_modulate  # loaded by the runs that use it (start-up)

        kw = asdict(config.diffusion)
        support = None
        if inputs.want_support:
            # a pixel is vouched for when its strongest diffusion weight reaches riverbed's gamma
            data, dref = diffusion_modulate(volume.data, inputs.sparse, inputs.image, volume.d_min,
                                            cost_scale=volume.scale, inplace=True,
                                            support_weight=config.guidance.gamma, tubes=volume.tubes, **kw)
            support = (dref, dref)
        else:
            data = diffusion_modulate(volume.data, inputs.sparse, inputs.image, volume.d_min,
                                      cost_scale=volume.scale, inplace=True, tubes=volume.tubes, **kw)
        return Guidance(volume.like(data, inputs.max_cost), None, support)
