"""Scale: tiled matching with LiDAR-driven disparity ranges (tiles.py), ``riverbed match`` on files
(match_files.py), and blocks of pairs on dask.distributed (block/)."""
