"""Stereo matching, split by stage as in CNES Pandora.

census.py   matching cost (census transform, Hamming cost volume)
guidance.py LiDAR guidance of the cost volume (Gauss enhancement, riverbed enhancement)
sgm.py      Semi-Global Matching aggregation (4, 8 or 16 paths)
disparity.py disparity selection and refinement (winner-takes-all, sub-pixel, median, left-right check)
pipeline.py match_pair: the stages in order, with timings
"""
