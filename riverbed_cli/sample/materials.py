"""Surface materials: the node attribute that drives colour, LiDAR class and LiDAR drop-outs."""

import numpy as np


# Materials (node attribute; drive colour, LiDAR class and LiDAR drop-outs).
GRASS, ROAD, FIELD, ROOF, TREE, WATER, TAR, CAR, SOLAR, SOIL, PAVING = range(11)
MATERIAL_NAMES = ("grass", "road", "field", "roof", "tree", "water", "tar roof", "car", "solar panel", "soil",
                  "paving")
#: ASPRS class of a LiDAR return by material (2 ground, 5 high vegetation, 6 building, 9 water, 1 unclassified).
MATERIAL_CLASS = np.array([2, 2, 2, 6, 5, 9, 6, 1, 6, 2, 2], np.uint8)
#: Probability that a pulse on a material gives no return (dark or wet surfaces).
MATERIAL_DROPOUT = np.array([0.0, 0.02, 0.0, 0.0, 0.0, 0.96, 0.75, 0.1, 0.5, 0.0, 0.0])
