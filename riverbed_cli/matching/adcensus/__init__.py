"""AD-Census stereo matching (Mei, Sun, Zhou, Jiao, Wang, Zhang 2011, "On building an accurate stereo matching system
on graphics hardware"), the second matcher riverbed's guidance is shown with.

One module per stage, each a function on numpy arrays; :func:`adcensus_disparity` runs them in order:

- ``params.py``: :class:`ADCensusParams` (defaults: the paper's) and :data:`GUIDE_STAGES`.
- ``cost.py``: 1. AD + census cost in fixed point (:func:`adcensus_cost`).
- ``cross.py``: 2. cross-based support regions (:func:`cross_arms`) and 3. aggregation over them
  (:func:`cross_aggregate`; :func:`adcensus_aggregate` fuses stages 1 and 3 without storing the cost volume).
- 4. guidance (optional, in :mod:`pipeline`): the aggregated volume is modulated with LiDAR disparities *before*
  scanline optimisation, as the census volume is before SGM (``guide_stage="initial"`` modulates the raw cost before
  aggregation instead).
- ``scanline.py``: 5. scanline optimisation over 4 paths (:func:`scanline_optimize`).
- ``refinement.py``: 6. left-right check, region voting, interpolation, discontinuity adjustment, sub-pixel fit
  (:func:`refine`); then a 3 x 3 median filter.

Where this differs from the paper: the right disparity map comes from the left volume (``min_d S(x_r + d, d)``), not
from a second matching pass; the crosses are the left image's only (Zhang et al.'s per-disparity intersection with the
right image's crosses measured slightly better, at about twice the aggregation cost: docs/riverbed_plus.md); costs
are fixed point (1/256 of the paper's unit).

Conventions: the left image is the reference; ``d = x_left - x_right``; volumes are ``H x W x D`` with
``d = d_min + i`` at index ``i``; images ``H x W x C`` ``uint8`` (0..255).
"""

import time

import numpy as np

from ...errors import RiverbedError
from .. import census
from ..disparity import median_filter
from .cost import adcensus_cost, cost_luts, to_u8, u8_image
from .cross import adcensus_aggregate, cross_aggregate, cross_arms, support_counts
from .params import GUIDE_STAGES, ADCensusParams
from .refinement import refine, region_voting, wta_lr_kernel
from .scanline import scanline_optimize, so_penalties

__all__ = ["ADCensusParams", "GUIDE_STAGES", "adcensus_aggregate", "adcensus_cost", "adcensus_disparity",
           "cost_luts", "cross_aggregate", "cross_arms", "refine", "region_voting", "scanline_optimize",
           "so_penalties", "support_counts", "to_u8", "wta_lr_kernel"]


def adcensus_disparity(left, right, d_min, d_max, params=None, census_window=(9, 7), grey=None, modulate=None,
                       subpixel=True, median=3, timings=None, return_status=False):
    """AD-Census disparity of a rectified pair (all stages, package docstring).

    Parameters
    ----------
    left, right : (H, W) or (H, W, C) uint8
        Images on a 0..255 scale (:func:`to_u8` of :func:`io.images.to_guide`).
    d_min, d_max : int
        Inclusive disparity range.
    params : ADCensusParams
    census_window : (int, int)
        Census window (width, height).
    grey : (left_grey, right_grey), optional
        Float grey images for the census transform (default: the channel mean of ``left`` / ``right``).
    modulate : callable, optional
        ``modulate(volume, max_cost) -> (volume, max_cost, support)``: guidance of the uint16 volume (cost units
        ``1 / params.scale``), called after cross aggregation (``guide_stage="aggregated"``, before scanline
        optimisation) or on the raw cost (``"initial"``); ``support`` is None or the ``(lo, hi)`` disparity
        interval the guidance vouches for per pixel (:func:`refine`).
    subpixel : bool
        Parabola sub-pixel fit. ``median``: median filter size (1: off).
    timings : dict, optional
        Filled with seconds per stage (cost, aggregation, guidance, optimisation, refinement).
    return_status : bool
        Add the left-right outcome map to ``info`` (:func:`refine`).

    Returns
    -------
    disparity : (H, W) float32
    info : dict
        Refinement counts (:func:`refine`).
    """
    p = params or ADCensusParams()
    if p.guide_stage not in GUIDE_STAGES:
        raise RiverbedError(f"unknown guide stage '{p.guide_stage}' (use {' or '.join(GUIDE_STAGES)})")
    timings = {} if timings is None else timings
    left = u8_image(left, "left")
    right = u8_image(right, "right")
    if left.shape != right.shape:
        raise RiverbedError(f"left and right images differ in shape: {left.shape} vs {right.shape}")
    t0 = time.perf_counter()
    if grey is None:
        grey = (left.mean(axis=2, dtype=np.float32), right.mean(axis=2, dtype=np.float32))
    cl = census.census_transform(grey[0], census_window)
    cr = census.census_transform(grey[1], census_window)
    max_cost = 2 * p.scale
    arms = cross_arms(left, p.arm_l1, p.arm_l2, p.arm_tau1, p.arm_tau2)
    timings["cost"] = time.perf_counter() - t0  # census transforms and crosses (the cost is fused below)

    support = None

    def guide(vol, max_cost):
        nonlocal support
        t = time.perf_counter()
        if modulate is not None:
            vol, max_cost, support = modulate(vol, max_cost)
        timings["guidance"] = time.perf_counter() - t
        return vol, max_cost

    work = []
    t0 = time.perf_counter()
    if p.guide_stage == "initial":
        cost = adcensus_cost(left, right, cl, cr, d_min, d_max, p.lambda_ad, p.lambda_census, p.scale, p.outside)
        timings["cost"] += time.perf_counter() - t0
        cost, max_cost = guide(cost, max_cost)
        t0 = time.perf_counter()
        agg = cross_aggregate(cost, arms, p.iterations, inplace=True, work=work)
    else:
        agg = adcensus_aggregate(left, right, cl, cr, d_min, d_max, arms, p, work)
    del cl, cr
    timings["aggregation"] = time.perf_counter() - t0
    if p.guide_stage == "aggregated":
        agg, max_cost = guide(agg, max_cost)
    t0 = time.perf_counter()
    scratch = [w for w in work if w.dtype == np.uint16]
    fwd, bwd = scanline_optimize(agg, left, right, d_min, p.pi1, p.pi2, p.tau_so, p.scale, max_cost,
                                 out=scratch[:2] if len(scratch) >= 2 else None)
    del agg, work, scratch
    timings["optimisation"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    disp, info = refine(fwd, bwd, d_min, left, arms, p, subpixel, return_status, support)
    del fwd, bwd
    disp = median_filter(disp, median)
    timings["refinement"] = time.perf_counter() - t0
    return disp, info
