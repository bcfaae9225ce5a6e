"""Aggregation: Semi-Global Matching (Hirschmueller 2008) over 4, 8 or 16 paths.

Each path cost follows ``L_r(p, d) = C(p, d) + min(L_r(p-r, d), L_r(p-r, d+-1) + P1, min_k L_r(p-r, k) + P2)
- min_k L_r(p-r, k)``, starting with ``L_r = C`` at the first pixel of every path. The aggregated cost is the sum over
paths. Costs and sums stay in ``uint16``.

Implementation: half of the directions are swept in one raster-order pass (top-left to bottom-right), the other half in
the reverse pass; each pass keeps the path costs of the last rows in a small ring buffer, so the cost volume is read
once per pass; a step works on whole chunks of ``LANES`` disparities at once (:mod:`.lanes`), dense and tube volumes
alike. A pass sweeps each row one direction at a time, every pixel adding into its own slot of a row of half-sums:
only the horizontal direction's steps depend on each other, so the CPU overlaps the others' (one pixel at a time,
with every direction's steps into one shared scratch, was 12-25 % slower). The last direction stores each pixel's
half-sum straight into the pass's result (masked to its tube; a copy of the row's half-sums after the sweep took a
fifth of the pass). The common steps (one chunk, or a wide tube beside a wide tube, the neighbour's entry within
reach) run in lean loops of their own, the rare cases in the pass's loop. At 4 paths on tubes a pixel's two
directions go in one step where both are common ones, one chunk or wide (:func:`.lanes.lanes_step_pair`,
:func:`.lanes.lanes_step_wide_pair`: the cost loaded once, no half-sum between them); the column's sweep takes the
rest. Where the row's neighbour's tube starts at the same disparity and takes as many chunks (nearly every step: the
tubes are made per cell, and a hole's pixels all search the whole range), the steps go in runs whose row path costs
stay in registers (:func:`.lanes_runs.lanes_run_pair`). The two passes are independent and run side by side, each
on half of the threads (the pass and its rows' hand-over between threads: :mod:`.sgm_pass`).
"""

import numpy as np
from numba import get_num_threads, prange

from ..errors import RiverbedError
from ..runtime.kernel import kernel
from .disparity import finish_selection, select_row
from .kernels.atomics import exchange, load_acquire
from .kernels.row_handover import MAX_PASS_THREADS, pass_threads
from .sgm_pass import pass_ring, sgm_rows
from .volume import band_pair_rows, band_pairs, volume_layout

# Directions (dx, dy) swept in the forward raster pass; the reverse pass sweeps their opposites.
_FORWARD_DIRS = {
    4: [(1, 0), (0, 1)],
    8: [(1, 0), (0, 1), (1, 1), (-1, 1)],
    16: [(1, 0), (0, 1), (1, 1), (-1, 1), (2, 1), (-2, 1), (1, 2), (-1, 2)],
}

def path_directions(paths):
    """All ``paths`` directions ``(dx, dy)`` (each path runs from ``p - r`` to ``p``)."""
    if paths not in _FORWARD_DIRS:
        raise RiverbedError(f"--paths must be 4, 8 or 16, not {paths}")
    fwd = _FORWARD_DIRS[paths]
    return fwd + [(-dx, -dy) for dx, dy in fwd]


@kernel
def _run_pass(t, flat, fwd, bwd, H, W, D, start, width, offset, wmax, dxs, dys, P1, P2, nf, nb, ring_f, ring_b,
              rows_done):
    # iteration t of the passes' parallel loop: the forward pass's threads first, then the reverse pass's; returns
    # which pass it ran (0 forward, 1 reverse). A pass on one thread makes its buffers itself: they start in its
    # core's cache (made by another thread, the 4-path tube passes took up to a quarter longer)
    p = 0 if t < nf else 1
    threads = nf if p == 0 else nb
    ring = (ring_f if p == 0 else ring_b) if threads > 1 else pass_ring(H, W, dxs.shape[0], wmax, 1)
    L, Lmin, rw, ro, progress, claim = ring
    sgm_rows(flat, fwd if p == 0 else bwd, H, W, D, start, width, offset, wmax, dxs, dys, P1, P2, p == 1, L, Lmin,
             rw, ro, progress, claim, threads, t - nf * p, rows_done, H * p)
    return p


@kernel
def _rings(H, W, nd, wmax, nf, nb):
    # the buffers of the passes on several threads, shared by them (tiny stand-ins for a pass on one thread)
    return (pass_ring(H, W, nd, wmax, nf) if nf > 1 else pass_ring(0, 0, 0, 0, 1),
            pass_ring(H, W, nd, wmax, nb) if nb > 1 else pass_ring(0, 0, 0, 0, 1))


@kernel(parallel=True)
def _sgm_two_passes(flat, fwd, bwd, H, W, D, start, width, offset, wmax, dxs, dys, P1, P2, threads):
    nf, nb = pass_threads(H, threads)
    ring_f, ring_b = _rings(H, W, dxs.shape[0], wmax, nf, nb)
    rows_done = np.zeros(2 * H, np.int64)
    for t in prange(nf + nb):
        _run_pass(t, flat, fwd, bwd, H, W, D, start, width, offset, wmax, dxs, dys, P1, P2, nf, nb, ring_f,
                  ring_b, rows_done)


@kernel(parallel=True)
def _sgm_select_kernel(flat, fwd, bwd, H, W, D, start, width, offset, wmax, dxs, dys, P1, P2, d_min, subpixel,
                       lr_check, lr_threshold, mark_failures, threads):
    # _sgm_two_passes, each row's disparity selected as soon as both passes hold it. Once its pass has no row left to
    # take, a thread selects the rows from its pass's far end (the rows the other pass did first), as long as both
    # passes have done them and no one took them, and stops at the first it cannot select; the rows left go to every
    # thread after. No thread waits for another pass: run one after the other (a single thread), the forward pass's
    # thread selects nothing and the reverse pass's everything.
    fu, bu = fwd.view(np.uint16), bwd.view(np.uint16)  # the half-sums as the selection reads them
    disp = np.empty((H, W), dtype=np.float32)
    status = np.zeros((H, W if mark_failures else 1), dtype=np.int8)  # mark_failures: 1 where the check fails
    taken = np.zeros(H, np.int64)  # 1: a thread has selected (or is selecting) the row
    nf, nb = pass_threads(H, threads)
    ring_f, ring_b = _rings(H, W, dxs.shape[0], wmax, nf, nb)
    rows_done = np.zeros(2 * H, np.int64)  # 1: the pass (forward at y, reverse at H + y) has done image row y
    for t in prange(nf + nb):
        p = _run_pass(t, flat, fwd, bwd, H, W, D, start, width, offset, wmax, dxs, dys, P1, P2, nf, nb, ring_f,
                      ring_b, rows_done)
        for k in range(H):
            y = H - 1 - k if p == 0 else k
            # the forward pass's threads take rows from the bottom (the reverse pass's first), the others from the top
            if (load_acquire(rows_done, y) == 0 or load_acquire(rows_done, H + y) == 0
                    or exchange(taken, y, 1) != 0):
                break
            select_row(fu, bu, y, W, D, start, width, offset, wmax, d_min, subpixel, lr_check, lr_threshold,
                       mark_failures, disp, status)
    m = band_pairs(H)
    for i in prange(m):  # the rows' shares of every row-parallel kernel of the match (volume.band_pair_rows)
        r0, r1 = band_pair_rows(i, m, H)
        for y in range(r0, r1):
            if taken[y] == 0:
                select_row(fu, bu, y, W, D, start, width, offset, wmax, d_min, subpixel, lr_check, lr_threshold,
                           mark_failures, disp, status)
    return disp, status


def sgm_aggregate_select(cost, p1, p2, d_min, paths=8, max_cost=None, tubes=None, subpixel=True, lr_check=False,
                         lr_threshold=1, return_status=False):
    """:func:`sgm_aggregate_passes` followed by :func:`.disparity.select_disparity` of its two half-sums (the same
    arguments; ``d_min`` the disparity at index 0), in one kernel: each row's disparity is selected as soon as both
    passes have done it, by the thread whose pass ended first while the other pass goes on, so that its core does
    not wait idle (run side by side, the reverse pass took 1.1-2x the forward pass's time on the speed pairs). The
    same result as the two functions, bit for bit; aggregation and selection 0.83-0.99x of their time on the speed
    pairs' 4-path tube volumes (docs/tubes.md).

    Returns the disparity (H, W) float32, or ``(disparity, status)`` with ``return_status`` (as
    :func:`.disparity.select_disparity`).
    """
    fwd, bwd, args = _passes_setup(cost, p1, p2, paths, max_cost, tubes)
    check = bool(lr_check or return_status)
    disp, status = _sgm_select_kernel(*args, int(d_min), bool(subpixel), check, int(lr_threshold),
                                      bool(return_status), get_num_threads())
    return finish_selection(disp, status, lr_check, return_status)


@kernel(parallel=True)
def _add_inplace(a, b):
    H = a.shape[0]
    for y in prange(H):
        ay = a[y]
        by = b[y]
        for x in range(ay.shape[0]):
            for d in range(ay.shape[1]):
                ay[x, d] = ay[x, d] + by[x, d]


def check_sgm_bounds(max_cost, p2, paths):
    """Raise if the summed path costs could overflow uint16 (each path cost is at most ``max_cost + P2``)."""
    bound = paths * (int(max_cost) + int(p2))
    if bound > 65535 or int(p2) >= 16384:
        raise RiverbedError(
            f"SGM sums could reach {bound} > 65535 with {paths} paths, max cost {max_cost} and P2 {p2}; "
            "lower P2 or the number of paths"
        )


def sgm_aggregate_passes(cost, p1, p2, paths=8, max_cost=None, tubes=None):
    """Forward and reverse half-sums of the path costs, ``(S_forward, S_reverse)``, both ``uint16 (H, W, D)``.

    Their sum is the aggregated cost; keeping them apart lets disparity selection fuse the addition.
    ``max_cost`` is a known upper bound of ``cost`` (spares a pass over the volume to find it). With ``tubes`` (a
    :class:`~riverbed_cli.matching.volume.TubeLayout`; ``cost`` and the results are flat tube volumes) the
    recurrence compares equal disparities of neighbours, and a disparity outside a neighbour's tube is unreachable
    there.
    """
    fwd, bwd, args = _passes_setup(cost, p1, p2, paths, max_cost, tubes)
    _sgm_two_passes(*args, get_num_threads())
    return fwd, bwd


@kernel(parallel=True)
def _forward_kernel(flat, fwd, H, W, D, start, width, offset, wmax, dxs, dys, P1, P2, threads):
    n = max(1, min(threads, MAX_PASS_THREADS, H))
    L, Lmin, rw, ro, progress, claim = pass_ring(H, W, dxs.shape[0], wmax, n)
    rows_done = np.zeros(H, np.int64)
    for t in prange(n):
        sgm_rows(flat, fwd, H, W, D, start, width, offset, wmax, dxs, dys, P1, P2, False, L, Lmin, rw, ro, progress,
                 claim, n, t, rows_done, 0)


def sgm_forward_pass(cost, p1, p2, paths=8, *, max_cost=None, tubes=None, threads=None):
    """The forward half-sum alone (``S_forward`` of :func:`sgm_aggregate_passes`, the same bits), its rows swept by
    ``threads`` threads (default: Numba's; at most :data:`~.kernels.row_handover.MAX_PASS_THREADS`): how one pass
    scales with the threads it is given (``benchmarks/bench_threads.py``). More threads than Numba runs give the same
    result (a thread takes the rows no other has taken)."""
    fwd, _, args = _passes_setup(cost, p1, p2, paths, max_cost, tubes)
    _forward_kernel(args[0], args[1], *args[3:], int(threads or get_num_threads()))
    return fwd


def _passes_setup(cost, p1, p2, paths, max_cost, tubes):
    # the checks, the two uint16 results and _sgm_two_passes's arguments (the results as int16 views: a half-sum is
    # <= 32767, the same bits)
    if (cost.ndim != (1 if tubes is not None else 3)) or cost.dtype not in (np.uint8, np.uint16):
        raise RiverbedError(f"cost volume must be uint8 or uint16 (H, W, D), got {cost.dtype} {cost.shape}")
    p1, p2 = int(p1), int(p2)
    if p1 < 0 or p2 < p1:
        raise RiverbedError(f"SGM penalties need 0 <= P1 <= P2 (got P1={p1}, P2={p2})")
    fwd_dirs = path_directions(paths)[: paths // 2]
    if max_cost is None:
        max_cost = int(cost.max()) if cost.size else 0
    check_sgm_bounds(max_cost, p2, paths)
    cost = np.ascontiguousarray(cost)
    dxs = np.array([d[0] for d in fwd_dirs], dtype=np.int64)
    dys = np.array([d[1] for d in fwd_dirs], dtype=np.int64)
    fwd = np.empty(cost.shape, dtype=np.uint16)
    bwd = np.empty(cost.shape, dtype=np.uint16)
    shape = tubes.shape if tubes is not None else cost.shape[:2]
    flat, W, D, start, width, offset = volume_layout(cost, shape, tubes)
    wmax = int(tubes.max_width) if tubes is not None else D
    return fwd, bwd, (flat, fwd.reshape(-1).view(np.int16), bwd.reshape(-1).view(np.int16), shape[0], W, D, start,
                      width, offset, wmax, dxs, dys, np.int32(p1), np.int32(p2))


def sgm_aggregate(cost, p1, p2, paths=8):
    """Semi-Global Matching aggregation.

    Parameters
    ----------
    cost : (H, W, D) uint8 or uint16
        Matching cost volume (disparity innermost).
    p1, p2 : int
        Penalties for a disparity change of one, and of more than one, between neighbours along a path
        (in the units of ``cost``), ``0 <= p1 <= p2``.
    paths : {4, 8, 16}
        Number of path directions.

    Returns
    -------
    (H, W, D) uint16
        Sum over all paths of the path costs ``L_r``.
    """
    fwd, bwd = sgm_aggregate_passes(cost, p1, p2, paths)
    _add_inplace(fwd, bwd)
    return fwd
