"""Reading and writing files: images, disparity maps, LiDAR (LAS/LAZ/COPC, KITTI .bin), pair files, GeoTIFFs,
point clouds, rasters read and written window by window (windowed.py), and the atomic-output helper."""
