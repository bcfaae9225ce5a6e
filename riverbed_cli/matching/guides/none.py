"""``none``: no guidance; the matcher runs on the images alone."""

from ..registry import register_guide
from .base import Guide, Guidance


@register_guide
class NoGuide(Guide):
    name = "none"
    needs_sparse = False

    def modulate(self, volume, inputs, config):
        return Guidance(volume)
