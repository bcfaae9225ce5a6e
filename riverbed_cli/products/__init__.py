"""Products made from disparity maps: DSMs and point clouds, evaluation against ground truth (disparity and DSM),
the benchmark protocol, simulated LiDAR, visualisations."""
