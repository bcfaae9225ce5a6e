"""The fusion plugin: what a fusion needs of the LiDAR before the matcher runs, and how it combines the two."""


class Fusion:
    """A way of combining the matcher's output with the LiDAR. ``needs_status``: it asks the matcher for its
    left-right check."""

    name = ""
    needs_status = False

    def prepare(self, sparse, config, points=None):
        """What the fusion needs of the ``sparse`` LiDAR alone (None: nothing), made before or beside the matcher
        and handed to :meth:`fuse` as ``prepared`` (``points``: ``lidar_points(sparse)`` if already found)."""
        return None

    def fuse(self, disparity, status, sparse, config, prepared=None):
        """A :class:`~riverbed_cli.matching.fusion.FusionOutput` from the matcher's ``disparity`` and ``status`` and
        the ``sparse`` LiDAR (``prepared``: :meth:`prepare`'s result for it, if made)."""
        raise NotImplementedError
