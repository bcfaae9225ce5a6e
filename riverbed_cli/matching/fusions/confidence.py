"""``confidence``: per pixel, the matcher's disparity or the LiDAR's interpolation, whichever is likelier
(:func:`~riverbed_cli.matching.fusion.fuse_disparity`, docs/fusion.md)."""

from ..fusion import fuse_disparity, lidar_model
from ..registry import register_fusion
from .base import Fusion


@register_fusion
class ConfidenceFusion(Fusion):
    """:func:`~riverbed_cli.matching.fusion.fuse_disparity` with the ``fusion_*`` settings; the LiDAR's model
    (:func:`~riverbed_cli.matching.fusion.lidar_model`) is prepared before or beside the matcher."""

    name = "confidence"
    needs_status = True

    def prepare(self, sparse, config, points=None):
        f = config.fuse
        return lidar_model(sparse, f.neighbours, f.support, f.floor, points, f.lidar)

    def fuse(self, disparity, status, sparse, config, prepared=None):
        f = config.fuse
        return fuse_disparity(disparity, status, sparse, f.gate, f.neighbours, f.support, f.floor, f.stereo_sigma,
                              prepared, f.lidar)
