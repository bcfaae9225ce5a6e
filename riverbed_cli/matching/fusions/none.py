"""``none``: the matcher's output as it is (the paper's method)."""

from ..fusion import FusionOutput
from ..registry import register_fusion
from .base import Fusion


@register_fusion
class NoFusion(Fusion):
    """The matcher's output as it is (the paper's method)."""

    name = "none"

    def fuse(self, disparity, status, sparse, config, prepared=None):
        return FusionOutput(disparity)
