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
- ``cross_tubes.py``: 3. on per-pixel tubes (:func:`cross_aggregate_tube`, exact; :func:`support_layouts`).
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
from .cost import adcensus_cost, adcensus_cost_tube, cost_luts, to_u8, u8_image
from .cross import adcensus_aggregate, cross_aggregate, cross_arms, support_counts
from .cross_tubes import cross_aggregate_tube, stage_plan, support_layouts
from .params import GUIDE_STAGES, ADCensusParams
from .refinement import refine, region_voting, wta_lr_kernel, wta_lr_tube_kernel
from .scanline import scanline_optimize, so_penalties

__all__ = ["ADCensusParams", "GUIDE_STAGES", "adcensus_aggregate", "adcensus_cost", "adcensus_cost_tube",
           "adcensus_disparity", "cost_luts", "cross_aggregate", "cross_aggregate_tube", "cross_arms", "refine",
           "region_voting", "scanline_optimize", "so_penalties", "stage_plan", "support_counts", "support_layouts",
           "to_u8", "wta_lr_kernel", "wta_lr_tube_kernel"]


def adcensus_disparity(left, right, d_min, d_max, params=None, census_window=(9, 7), grey=None, modulate=None,
                       subpixel=True, median=3, timings=None, return_status=False, tubes=None):
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
        ``modulate(volume, max_cost, layout) -> (volume, max_cost, support)``: guidance of the uint16 volume (cost
        units ``1 / params.scale``), called after cross aggregation (``guide_stage="aggregated"``, before scanline
        optimisation) or on the raw cost (``"initial"``); ``layout`` is None for a dense volume or the
        :class:`~riverbed_cli.matching.volume.TubeLayout` of the flat one; ``support`` is None or the ``(lo, hi)``
        disparity interval the guidance vouches for per pixel (:func:`refine`).
    subpixel : bool
        Parabola sub-pixel fit. ``median``: median filter size (1: off).
    timings : dict, optional
        Filled with seconds per stage (cost, aggregation, guidance, optimisation, refinement).
    return_status : bool
        Add the left-right outcome map to ``info`` (:func:`refine`).
    tubes : TubeLayout, optional
        Per-pixel tubes inside ``[d_min, d_max]``: every stage works on them (docs/tubes.md, "AD-Census"). The
        cost is computed on the support layouts of the cross aggregation (:func:`support_layouts`), so the
        aggregated cost at every tube disparity equals the full-range one; scanline optimisation treats a
        disparity outside the previous pixel's tube as unreachable; the refinement as :func:`refine` with tubes.

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

    def guide(vol, max_cost, layout=None):
        nonlocal support
        t = time.perf_counter()
        if modulate is not None:
            vol, max_cost, support = modulate(vol, max_cost, layout)
        timings["guidance"] = time.perf_counter() - t
        return vol, max_cost

    if tubes is not None:
        return _tube_disparity(left, right, cl, cr, d_min, d_max, arms, p, guide, lambda: support, subpixel, median,
                               timings, return_status, tubes, time.perf_counter())
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


def _tube_disparity(left, right, cl, cr, d_min, d_max, arms, p, guide, get_support, subpixel, median, timings,
                    return_status, tubes, t0):
    # the stages of adcensus_disparity on tube volumes (t0: when the cost stage started)
    if tubes.shape != left.shape[:2]:
        raise RiverbedError(f"tube layout {tubes.shape} and images {left.shape[:2]} differ in size")
    max_cost = 2 * p.scale
    layouts = support_layouts(tubes, arms, p.iterations, d_min)
    cost = adcensus_cost_tube(left, right, cl, cr, d_min, layouts[0], p.lambda_ad, p.lambda_census, p.scale,
                              p.outside)
    timings["cost"] += time.perf_counter() - t0
    support_costs = int(layouts[0].size)
    if p.guide_stage == "initial":
        cost, max_cost = guide(cost, max_cost, layouts[0])
    t0 = time.perf_counter()
    agg = cross_aggregate_tube(cost, arms, p.iterations, layouts)
    del cost, layouts
    timings["aggregation"] = time.perf_counter() - t0
    if p.guide_stage == "aggregated":
        agg, max_cost = guide(agg, max_cost, tubes)
    t0 = time.perf_counter()
    fwd, bwd = scanline_optimize(agg, left, right, d_min, p.pi1, p.pi2, p.tau_so, p.scale, max_cost, tubes=tubes)
    del agg
    timings["optimisation"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    disp, info = refine(fwd, bwd, d_min, left, arms, p, subpixel, return_status, get_support(), tubes,
                        int(d_max) - int(d_min) + 1)
    info["support_costs"] = support_costs  # raw costs computed (the first support layout), against tubes.size
    del fwd, bwd
    disp = median_filter(disp, median)
    timings["refinement"] = time.perf_counter() - t0
    return disp, info
