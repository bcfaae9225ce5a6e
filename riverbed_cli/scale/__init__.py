"""Scale: tiled matching with LiDAR-driven disparity ranges, and blocks of pairs on dask.distributed."""
