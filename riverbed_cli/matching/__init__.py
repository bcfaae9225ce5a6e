"""Stereo matching, split by stage as in CNES Pandora; matchers and guides chosen by name from registries.

Stages (plain functions on numpy arrays; volumes ``H x W x D``, ``d = d_min + i``):

census.py        matching cost: census transform, Hamming cost volume
guidance.py      LiDAR guidance kernels: Gauss enhancement, riverbed enhancement (eqs. 2, 3, 5, 6)
diffusion.py     diffusion guidance (Shivakumar et al. 2019)
riverbed_plus.py riverbed+ guidance (riverbed through cross-based support regions)
sgm.py           aggregation: Semi-Global Matching (4, 8 or 16 paths); sgm_pass.py: its pass over the rows
disparity.py     selection and refinement: winner-takes-all, sub-pixel, left-right check, median
adcensus/        the AD-Census matcher's stages: cost, cross aggregation, scanline optimisation, refinement

Assembly:

config.py        the settings table (MATCH_SETTINGS) and the frozen, nested MatchConfig
registry.py      MATCHERS and GUIDES, filled by register_matcher / register_guide
matchers/        sgm, adcensus: each runs its stages on a CostVolume (volume.py) with a guide
guides/          none, gauss, riverbed, diffusion, riverbed+: what each needs and how it modulates the volume
fusions/         none, confidence: what each needs of the LiDAR and how it combines it with the match
lidar_input.py   the LiDAR entering a match: checked, the range derived from it, cut to the range
range_maps.py    per-pixel ranges besides the tubes: range maps checked, the tube holes' coarse match
pipeline.py      match_pair: checks the inputs, runs the guide's preparation and the matcher; results.py
"""
