"""Changed regions of the LiDAR check (:mod:`.lidar_check`): the cells where the images contradict the LiDAR, the
spread of a change over the points, its fringe, and the changed area round its points.

Stage: ``(points' pixels, values, verdicts) -> the points a change takes and the area it covers``. The points are
given as ``rows, cols, values`` (LiDAR pixels of the left image and their disparities, px) and ``index``, the
point at each pixel (-1: none); a point's state is +1 / -1 (the images contradict it: LiDAR above / below them), 0
(they cannot judge it) or 2 (the reference confirms it).
"""

import cv2
import numpy as np
from numba import prange

from ..runtime.kernel import kernel

#: a cell is changed when this share of its points with an alternative disagree with the same sign ...
REGION_SHARE = 0.6
#: ... and at least this many do
MIN_POINTS = 3
#: changed regions grow into neighbouring cells where this share disagrees the same way
GROW_SHARE = 0.3


def cell_regions(rows, cols, verdict, has_alt, shape, side):
    """The changed cells of a ``side`` px grid over an image of ``shape``, from the points' verdicts (+1 / -1 /
    0; ``has_alt``: the points with a reference): seeds where at least :data:`REGION_SHARE` of a cell's points
    with a reference disagree the same way (at least :data:`MIN_POINTS`), closed, grown into cells where
    :data:`GROW_SHARE` do. Returns the (gh, gw) bool grid and each point's cell (flat index)."""
    H, W = shape
    gh, gw = -(-H // side), -(-W // side)
    cell = (rows // side) * gw + cols // side
    n = np.bincount(cell[has_alt], minlength=gh * gw).reshape(gh, gw)
    up = np.bincount(cell[verdict > 0], minlength=gh * gw).reshape(gh, gw)
    down = np.bincount(cell[verdict < 0], minlength=gh * gw).reshape(gh, gw)
    with np.errstate(invalid="ignore", divide="ignore"):
        share_up, share_down = up / n, down / n
    regions = np.zeros((gh, gw), np.uint8)
    for votes, share in ((up, share_up), (down, share_down)):
        seed = (votes >= MIN_POINTS) & (share >= REGION_SHARE)
        if not seed.any():
            continue
        grid = cv2.morphologyEx(seed.astype(np.uint8), cv2.MORPH_CLOSE, np.ones((3, 3), np.uint8))
        grow = (share >= GROW_SHARE) & (votes >= 1)
        grid = grid.astype(bool) & (n > 0) | seed
        for _ in range(max(gh, gw)):  # grow while neighbouring cells agree
            more = cv2.dilate(grid.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool) & grow & ~grid
            if not more.any():
                break
            grid |= more
        regions |= grid.astype(np.uint8)
    return regions.astype(bool), cell


def changed_area(rows, cols, shape, spacing):
    """The changed points' surroundings, (H, W) bool: a disc of one ``spacing`` (px) round each, closed over two."""
    # drawn in the points' bounding box with a margin the closing cannot reach past (3 r out, 2 r back), which
    # gives the same area as the whole image at a fraction of the cost
    r = max(1, int(round(spacing)))
    m = 6 * r + 1
    y0, y1 = max(0, int(rows.min()) - m), min(shape[0], int(rows.max()) + m + 1)
    x0, x1 = max(0, int(cols.min()) - m), min(shape[1], int(cols.max()) + m + 1)
    box = np.zeros((y1 - y0, x1 - x0), np.uint8)
    box[rows - y0, cols - x0] = 1
    box = cv2.dilate(box, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1)))
    box = cv2.morphologyEx(box, cv2.MORPH_CLOSE, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (4 * r + 1, 4 * r + 1)))
    area = np.zeros(shape, bool)
    area[y0:y1, x0:x1] = box.astype(bool)
    return area


@kernel
def flood(index, rows, cols, values, radius, state, seeds, hops, step, lean, level, tol):
    """The points (bool) a change reaches from its seeds (``seeds[i]``: its sign, 0 none; ``level[i]``: its change,
    px), neighbours being the points within a square of half side ``radius`` px: through points contradicted that
    way (``state == sign``) freely, and through those whose ``lean`` (the reference's ``LiDAR - images`` where only
    the reference disagrees, NaN elsewhere) lies within ``tol`` px of the seed's change; through the others (0, or
    the other sign) ``hops`` in a row and only along the LiDAR's surface (``values`` within ``step`` px of the point
    before, and within half the change); never through confirmed ones (2)."""
    # breadth first; a point is taken with the most hops left it can be reached with
    H, W = index.shape
    n = state.size
    left = np.full(n, -1, np.int64)
    sign = np.zeros(n, np.int8)
    change = np.zeros(n, np.float64)
    queue = np.empty(n * (hops + 2), np.int64)
    head, tail = 0, 0
    for i in range(n):
        if seeds[i] != 0:
            left[i] = hops
            sign[i] = seeds[i]
            change[i] = level[i]
            queue[tail] = i
            tail += 1
    while head < tail:
        i = queue[head]
        head += 1
        for y in range(max(0, rows[i] - radius), min(H, rows[i] + radius + 1)):
            for x in range(max(0, cols[i] - radius), min(W, cols[i] + radius + 1)):
                j = index[y, x]
                if j < 0 or state[j] == 2:
                    continue
                same = state[j] == sign[i] or abs(lean[j] - change[i]) <= tol  # False for a NaN lean
                # an unjudged point continues the stale surface only nearer it than the images' (half the change)
                if not same and abs(values[j] - values[i]) > min(step, 0.5 * abs(change[i])):
                    continue
                budget = hops if same else left[i] - 1
                if budget > left[j] and tail < queue.size:
                    left[j] = budget
                    sign[j] = sign[i]
                    change[j] = change[i]
                    queue[tail] = j
                    tail += 1
    return left >= 0


@kernel(parallel=True)
def fringe(index, rows, cols, values, radius, state, taken, tau):
    """A change's points (``taken``, bool) with the fringe its spread left: a point the reference does not confirm
    (``state != 2``) joins when most of its neighbours on its own surface (``values`` within ``tau`` px of its,
    in the square of half side ``radius`` px) are in the change, round after round until none does. Its neighbours
    on another surface (the clean LiDAR round a stale block) do not count."""
    # each round judges on the last round's change, so the result does not depend on the order of the points (nor
    # on the threads: the first loop only ever writes True). Only the points near the last round's newcomers are
    # judged again: the others' counts have not changed since they failed
    H, W = index.shape
    n = values.size
    out = np.zeros(n, np.bool_)
    fresh = np.zeros(n, np.bool_)
    for i in range(n):
        out[i] = taken[i]
        fresh[i] = taken[i]
    while True:
        near = np.zeros(n, np.bool_)  # the candidates: a newcomer to the change within the square
        for i in prange(n):
            if fresh[i]:
                for y in range(max(0, rows[i] - radius), min(H, rows[i] + radius + 1)):
                    for x in range(max(0, cols[i] - radius), min(W, cols[i] + radius + 1)):
                        j = index[y, x]
                        if j >= 0 and not out[j] and state[j] != 2:
                            near[j] = True
        add = np.zeros(n, np.bool_)
        for j in prange(n):
            if not near[j]:
                continue
            same, inside = 0, 0
            for y in range(max(0, rows[j] - radius), min(H, rows[j] + radius + 1)):
                for x in range(max(0, cols[j] - radius), min(W, cols[j] + radius + 1)):
                    k = index[y, x]
                    if k >= 0 and k != j and abs(values[k] - values[j]) <= tau:
                        same += 1
                        if out[k]:
                            inside += 1
            add[j] = 2 * inside > same
        grew = False  # plain loops: array methods would load Numba's array maths with the cached kernel
        for j in range(n):
            fresh[j] = add[j]
            if add[j]:
                out[j] = True
                grew = True
        if not grew:
            return out
