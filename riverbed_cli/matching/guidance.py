"""LiDAR guidance of the matching cost volume: Gauss enhancement and riverbed enhancement.

Sparse LiDAR disparities ``d_m`` of the left image lower the cost near ``d_m`` and raise it elsewhere:

* ``gauss`` (Poggi et al. 2019, paper eq. 5) at the LiDAR pixels only;
* ``riverbed`` (Zhang, Zou et al., eqs. 2, 3, 6) at the LiDAR pixels (as ``gauss``) and at their *homogeneous*
  pixels: pixels in an ``s x s`` window around a LiDAR point whose bilateral similarity
  ``1 - W = exp(-|p - p_L|^2 / 2 sigma_xy^2 - |I(p) - I(p_L)|^2 / 2 sigma_I^2)`` is at least ``gamma``. Each pixel
  belongs to at most one LiDAR point (the most similar one: the ownership image) and LiDAR pixels belong to
  themselves. A homogeneous pixel's cost is shrunk to ``W * F`` inside a band ``|d - d_m| <= band * W`` (the less
  similar the pixel, the wider the band: it is less certain to share ``d_m``) and rises outside it along Gaussian
  walls that start at the band edges (continuous there).

Wall forms (``form``): ``"additive"`` adds ``k * F_bar * (1 - exp(-t^2 / 2c^2))`` where ``t`` is the distance past the
band and ``F_bar`` the mean cost at the LiDAR pixels (a zero census cost can still be pushed up);
``"product"`` multiplies: ``k * (1 - exp(-t^2 / 2c^2)) * F`` (the paper's literal form; a zero cost stays zero).
At a LiDAR pixel: additive ``F + wall``; product ``k * (1 - exp(-(d - d_m)^2 / 2c^2)) * F`` (minimum 0 at ``d_m``).

The guided volume is ``uint16``: every cost (guided or not) is multiplied by ``cost_scale`` and rounded, so SGM
penalties must be scaled by the same factor; guided costs are clipped at ``max_cost`` to keep SGM sums within uint16.
The paper writes ``d_m = x_R - x_L``; here ``d = x_left - x_right >= 0`` throughout.
"""

import math

import numpy as np
from numba import prange

from ..errors import RiverbedError
from .volume import band_pair_rows, band_pairs, volume_layout
from ..geometry.coverage import (lidar_points, lidar_share, lidar_share_of_points,  # noqa: F401  (re-exported)
                                 pixels_where)
from ..geometry.interpolation import first_at_least
from ..runtime.kernel import kernel
from .kernels.lanes import LANES
from .kernels.lanes_guidance import (lanes_claim, lanes_claim_rgb, lanes_claim_rgb_whole, lanes_claim_whole,
                                     lanes_colour, lanes_colour_whole, lanes_flat, lanes_flat_whole, lanes_walls,
                                     lanes_walls_half_whole, lanes_walls_whole)

FORMS = {"additive": 0, "product": 1}


def auto_window(share, target=4.0, smallest=5, largest=25):
    """Riverbed window ``s`` for a LiDAR share ``p``: the smallest odd ``s`` with ``s * s * p >= target``.

    The default target 4 (about four LiDAR points per window) was measured better than the paper's ``s * s * p >= 1``
    on the Middlebury dev scenes and on the held-out KITTI frame at 5 % and 1.23 % LiDAR (docs/method.md).

    Clipped to ``[smallest, largest]``: with ``sigma_xy = 8`` and ``gamma = 0.3`` distance alone stops the homogeneous
    region about 12 px from its LiDAR point, so windows beyond 25 change nothing.
    """
    if share <= 0:
        return largest
    s = int(math.ceil(math.sqrt(target / share)))
    s += 1 - s % 2
    return int(min(max(s, smallest), largest))


@kernel(inline=True)
def _claim(j, rows, cols, planes, H, W, C, half, spatial, sw, b, e_lo, e_hi, owner, dissim, dd, ya, yb):
    # Offer LiDAR point j's window to its pixels in rows ya to yb - 1; a pixel keeps the most similar point (ties:
    # lower index), so the result does not depend on the order in which points are offered. Works on the exponent e
    # of eq. 2 (W = 1 - exp(-e), increasing in e): no exp in the loop; pixels with e outside [e_lo, e_hi] are not
    # homogeneous.
    # planes: the guide channel by channel (C, H, W), owner and dissim (H, W), all flat; a window row goes LANES
    # pixels at a time (lanes.lanes_colour, lanes.lanes_claim): Numba's own loops over these short rows did not
    # vectorise (docs/tubes.md). A LiDAR pixel (dissim 0) is never taken: e > e_lo >= 0 there.
    r0 = rows[j]
    c0 = cols[j]
    ca = max(0, c0 - half)
    n = min(W, c0 + half + 1) - ca
    for r in range(max(ya, r0 - half), min(yb, r0 + half + 1)):
        for i0 in range(0, n, LANES):
            c = ca + i0
            whole = c + LANES <= W  # the chunk inside the row: whole-vector loads and stores
            k = r * W + c
            si = (r - r0 + half) * sw + c - c0 + half  # the spatial terms of this chunk's lanes
            if C == 3:  # an RGB guide: its three distances in registers
                p0 = r0 * W + c0
                if whole:  # k: the pixel's index in the first plane as in owner and dissim
                    lanes_claim_rgb_whole(planes, k, H * W, planes[p0], planes[H * W + p0], planes[2 * H * W + p0],
                                          dissim, owner, k, spatial, si, b, e_lo, e_hi, j, n - i0)
                else:  # the row's last pixels: masked, the next row may be another thread's
                    lanes_claim_rgb(planes, k, H * W, planes[p0], planes[H * W + p0], planes[2 * H * W + p0],
                                    dissim, owner, k, spatial, si, b, e_lo, e_hi, j, n - i0)
                continue
            for ch in range(C):
                ref = planes[(ch * H + r0) * W + c0]
                if whole:
                    lanes_colour_whole(planes, (ch * H + r) * W + c, ref, dd, ch == 0, n - i0)
                else:
                    lanes_colour(planes, (ch * H + r) * W + c, ref, dd, ch == 0, n - i0)
            if whole:
                lanes_claim_whole(dissim, owner, k, dd, spatial, si, b, e_lo, e_hi, j, n - i0)
            else:
                lanes_claim(dissim, owner, k, dd, spatial, si, b, e_lo, e_hi, j, n - i0)


@kernel
def spatial_terms(half, a):
    """The spatial terms ``(dr^2 + dc^2) a`` of the ownership's exponent (float64), flat, ``sw`` per window row:
    ``dr`` from ``-half`` to ``half`` (rows), ``dc`` from ``-half`` to ``sw - half - 1`` (columns; ``sw`` reaches
    ``LANES`` lanes past the window's last chunk). Returns ``(table, sw)``."""
    sw = 3 * half + LANES + 1
    t = np.empty((2 * half + 1) * sw, np.float64)
    for r in range(2 * half + 1):
        for c in range(sw):
            t[r * sw + c] = np.float64((r - half) ** 2 + (c - half) ** 2) * a
    return t, sw


@kernel(parallel=True)
def _owners_kernel(rows, cols, guide, half, sigma_xy, sigma_i, gamma, literal):
    # rows are sorted (row-major order of the points). Each thread offers the points to the pixels of its own rows
    # only (volume.band_pair_rows, as every row-parallel kernel of the match), so no pixel is written by both
    # threads; the result does not depend on the order (_claim). Bands of at least 2 * half rows, the even ones
    # offered first and then the odd ones, wrote half of each other's rows: slower, most where the VM's two vCPUs do
    # not share their caches (docs/tubes.md, Speed).
    H, W, C = guide.shape
    planes = np.empty((C, H, W), np.float32)
    owner = np.empty((H, W), dtype=np.int32)
    dissim = np.empty((H, W), dtype=np.float64)  # float64 while comparing, so ties are real ties
    nr = band_pairs(H)
    for i in prange(nr):  # the rows' shares of every row-parallel kernel of the match (volume.band_pair_rows)
        r0, r1 = band_pair_rows(i, nr, H)
        for y in range(r0, r1):
            for ch in range(C):  # channel by channel: the writes in order (0.6x the time of pixel by pixel)
                for x in range(W):
                    planes[ch, y, x] = np.float32(guide[y, x, ch])  # a uint8 guide's samples exactly
            owner[y] = -1  # filled here in parallel (np.full is one thread's)
            dissim[y] = np.inf
            for j in range(first_at_least(rows, y), first_at_least(rows, y + 1)):  # the LiDAR pixels: their own
                owner[y, cols[j]] = j
                dissim[y, cols[j]] = 0.0
    pflat, oflat, dflat = planes.reshape(-1), owner.reshape(-1), dissim.reshape(-1)
    a = 1.0 / (2.0 * sigma_xy * sigma_xy)
    b = 1.0 / (2.0 * sigma_i * sigma_i * C)  # mean over channels of the squared colour difference
    # Homogeneous: 1 - W >= gamma, i.e. e <= -ln(gamma); eq. 3 as printed (W > gamma): e > -ln(1 - gamma).
    if literal:
        e_lo, e_hi = -math.log(1.0 - gamma), np.inf
    else:
        e_lo, e_hi = 0.0, -math.log(gamma)
    spatial, sw = spatial_terms(half, a)
    # each thread offers its own rows, from every point whose window reaches them: no pixel is written by both
    # threads (points near a share's edge are offered by both, each to its own rows)
    for i in prange(nr):
        r0, r1 = band_pair_rows(i, nr, H)
        dd = np.empty(LANES, np.float64)
        for j in range(first_at_least(rows, r0 - half), first_at_least(rows, r1 + half)):
            _claim(j, rows, cols, pflat, H, W, C, half, spatial, sw, b, e_lo, e_hi, oflat, dflat, dd, r0, r1)
    # exponent -> W (0 stays 0 at LiDAR pixels, inf stays inf where there is no owner): by a polynomial where it
    # gives libm's bits for sure (it vectorises), else by libm (a rare tie, the literal reading's far e)
    w = np.empty((H, W), np.float32)
    for i in prange(nr):
        r0, r1 = band_pair_rows(i, nr, H)
        for y in range(r0, r1):
            _weights_row(dissim[y], w[y])
    return owner, w


@kernel(inline=True)
def _weights_row(e, w):
    for x in range(e.shape[0]):
        w[x] = _weight_sure(e[x])
    for x in range(e.shape[0]):
        if w[x] != w[x]:
            w[x] = np.float32(-math.expm1(-e[x]))


@kernel
def ownership_weights(e):
    """``W = 1 - exp(-e)`` of paper eq. 2 as float32 from the exponents ``e >= 0`` (1-D float64; ``inf`` gives
    ``inf``, no owner), as :func:`homogeneous_owners` computes it: ``float32(-expm1(-e))`` to the bit."""
    w = np.empty(e.shape[0], np.float32)
    _weights_row(e, w)
    return w


#: -expm1(-e) = sum over k >= 1 of (-1)^(k+1) e^k / k! to k = 18 (below, by Horner): under 1e-14 relative for
#: 0 <= e <= _E_SURE
_E_SURE = 1.25  # covers the default reading's exponents (e <= -ln(gamma), 1.2 at gamma 0.3)


@kernel(inline=True)
def _weight_sure(e):
    # float32(-expm1(-e)) where the polynomial's float64 value (1e-14 off) and anything within 1e-12 of it round
    # to the same float32 (then libm's, also within, does too: the same bits); inf for inf (no owner); NaN where not
    # sure
    x = min(e, _E_SURE)
    p = -1.5619206968586225e-16
    p = p * x + 2.8114572543455206e-15
    p = p * x + -4.779477332387385e-14
    p = p * x + 7.647163731819816e-13
    p = p * x + -1.1470745597729725e-11
    p = p * x + 1.6059043836821613e-10
    p = p * x + -2.08767569878681e-09
    p = p * x + 2.505210838544172e-08
    p = p * x + -2.755731922398589e-07
    p = p * x + 2.7557319223985893e-06
    p = p * x + -2.48015873015873e-05
    p = p * x + 0.0001984126984126984
    p = p * x + -0.001388888888888889
    p = p * x + 0.008333333333333333
    p = p * x + -0.041666666666666664
    p = p * x + 0.16666666666666666
    p = p * x + -0.5
    p = p * x + 1.0
    p = p * x
    f = np.float32(p)
    sure = e <= _E_SURE and np.float32(p * (1.0 - 1e-12)) == np.float32(p * (1.0 + 1e-12))
    return f if sure else (np.float32(np.inf) if e == np.inf else np.float32(np.nan))


def guide_image(guide, shape, keep_uint8=False):
    """The left image for colour similarities as contiguous float32 ``H x W x C`` (a grey image gets ``C = 1``),
    checked against the sparse map's ``shape``; with ``keep_uint8`` a ``uint8`` image stays ``uint8`` (its samples
    are the 0..255 scale's float32 values exactly)."""
    guide = np.asarray(guide)
    if not (keep_uint8 and guide.dtype == np.uint8):
        guide = np.asarray(guide, dtype=np.float32)
    if guide.ndim == 2:
        guide = guide[:, :, None]
    if guide.shape[:2] != tuple(shape):
        raise RiverbedError(f"guide image {guide.shape[:2]} and sparse map {tuple(shape)} differ in size")
    return np.ascontiguousarray(guide)


def homogeneous_owners(sparse, guide, window, sigma_xy=8.0, sigma_i=8.0, gamma=0.3, literal_eq3=False, points=None):
    """Ownership image of the riverbed enhancement.

    Parameters
    ----------
    sparse : (H, W) float
        Sparse disparities of the left image, NaN where there is no LiDAR.
    guide : (H, W) or (H, W, C) float, or uint8
        Left image on a 0..255 scale (colour differences are averaged over channels). A ``uint8`` image is read as
        it is (the kernel takes its samples to float32 as it lays out its planes: no float copy of the image).
    window : int
        Odd side ``s`` of the square window around each LiDAR point.
    literal_eq3 : bool
        Select pixels with ``W > gamma`` as eq. 3 is printed (the *least* similar ones), only to reproduce that
        reading; the default keeps the similar ones, ``1 - W >= gamma``.
    points : tuple, optional
        ``lidar_points(sparse)`` if already found.

    Returns
    -------
    owner : (H, W) int32
        Index (into :func:`lidar_points` order) of the LiDAR point a pixel belongs to, -1 for none.
    dissimilarity : (H, W) float32
        ``W`` of paper eq. 2 towards the owner (0 at LiDAR pixels), ``inf`` where there is no owner.
    """
    window = int(window)
    if window < 1 or window % 2 == 0:
        raise RiverbedError(f"riverbed window must be a positive odd number, got {window}")
    guide = guide_image(guide, sparse.shape, keep_uint8=True)
    rows, cols, _ = lidar_points(sparse) if points is None else points
    return _owners_kernel(rows, cols, guide, window // 2,
                          float(sigma_xy), float(sigma_i), float(gamma), bool(literal_eq3))


@kernel(inline=True)
def _modulate_pixel(flat, base, D, d_min, dm, w, limit, k, band, form, scale, wall_scale, inv2c2, tfar, ceiling):
    # one guided pixel's D costs from flat[base] (disparity d_min first): its LiDAR point's disparity dm, its weight w
    # (0 at a LiDAR pixel); chunks ending before limit are read and written whole
    lidar_pixel = w == 0.0
    if form == 0:
        alpha, beta, gamma = (1.0 if lidar_pixel else w), 0.0, scale * k * wall_scale
    else:
        alpha, beta, gamma = (0.0 if lidar_pixel else w), k, 0.0
    half = band * w
    # indices whose wall is not yet flat: |d - dm| < half + tfar
    lo = min(D, max(0, int(math.floor(dm - half - tfar)) - d_min))
    hi = max(lo, min(D, int(math.ceil(dm + half + tfar)) - d_min + 1))
    a1 = np.float32(alpha + beta)
    g1 = np.float32(gamma + 0.5)  # + 0.5: truncating a positive value then rounds
    if D <= LANES // 2 and base + LANES // 2 <= limit:  # most tubes: half the lanes, walls or flat alike
        lanes_walls_half_whole(flat, base, 0, d_min, dm + half, dm - half, lo, hi, alpha, beta, gamma, a1, g1,
                               inv2c2, ceiling, D)
        return
    # LANES disparities at a time, the wall's Gaussian by a polynomial (lanes.lanes_walls): the scalar loops
    # with a multiplicative recurrence for the Gaussians took 2-2.3x as long for the same bits on the dev pairs
    for i0 in range(0, D, LANES):
        whole = base + i0 + LANES <= limit
        if i0 >= hi or i0 + LANES <= lo:  # flat all along: no wall to evaluate
            if whole:
                lanes_flat_whole(flat, base + i0, a1, g1, ceiling, D - i0)
            else:
                lanes_flat(flat, base + i0, a1, g1, ceiling, D - i0)
        elif whole:
            lanes_walls_whole(flat, base + i0, i0, d_min, dm + half, dm - half, lo, hi, alpha, beta, gamma,
                              a1, g1, inv2c2, ceiling, D - i0)
        else:
            lanes_walls(flat, base + i0, i0, d_min, dm + half, dm - half, lo, hi, alpha, beta, gamma, a1, g1,
                        inv2c2, ceiling, D - i0)


@kernel(parallel=True)
def _modulate_kernel(flat, W, D0, owner, dissim, values, d_min0, k, c, band, form, scale, wall_scale, max_cost, tstart,
                     twidth, toffset):
    # In place, only at the guided pixels (owner >= 0). flat holds
    # q = scale * F (a dense H x W x D0 volume flattened, or with tstart/twidth/toffset, 0 x 0 for none, per-pixel
    # tubes); every form is out = (alpha + beta * g) * q + gamma * g with the wall height g in [0, 1] (module
    # docstring).
    inv2c2 = 1.0 / (2.0 * c * c)
    tfar = 6.5 * c  # past this, 1 - exp(-t^2 / 2c^2) == 1 to 1e-9: the wall is flat and needs no exp
    ceiling = np.float32(max_cost)
    tube = tstart.shape[0] > 0
    H = owner.shape[0]
    # The rows' shares of every row-parallel kernel of the match (volume.band_pair_rows), each pair in order (no list
    # of the guided pixels: finding it took 0.2-0.3 ms on the speed pairs, 2.2 on the 1 MP aerial tile). A chunk of
    # LANES disparities may reach past its pixel's tube into the next pixels' (or the volume's end): inside the pair
    # (before its limit, the start of the next pair's first row) those are this thread's, to come, or nobody's, and
    # whole vectors are read and written back; past the limit the chunk is masked.
    m = band_pairs(H)
    for i in prange(m):
        r0, r1 = band_pair_rows(i, m, H)
        if r1 < H:
            limit = tstart[r1, 0] if tube else r1 * W * D0
        else:
            limit = flat.shape[0]
        for y in range(r0, r1):
            for x in range(W):
                o = owner[y, x]
                if o < 0:
                    continue
                if tube:
                    base, D, d_min = tstart[y, x], np.int64(twidth[y, x]), d_min0 + np.int64(toffset[y, x])
                else:
                    base, D, d_min = (y * W + x) * D0, D0, d_min0  # index 0 of this pixel is disparity d_min
                _modulate_pixel(flat, base, D, d_min, values[o], np.float64(dissim[y, x]), limit, k, band, form,
                                scale, wall_scale, inv2c2, tfar, ceiling)


def check_volume(cost, sparse, tubes=None):
    """A cost volume (H, W, D), or a flat tube volume with its layout, and a sparse map (H, W) of the same image;
    :class:`RiverbedError` otherwise."""
    if tubes is not None:
        volume_layout(cost, sparse.shape, tubes)
        return
    if cost.ndim != 3:
        raise RiverbedError(f"cost volume must be (H, W, D), got shape {cost.shape}")
    if sparse.shape != cost.shape[:2]:
        raise RiverbedError(f"sparse map {sparse.shape} and cost volume {cost.shape[:2]} differ in size")


def scaled_volume(cost, cost_scale, inplace):
    """The uint16 volume to modulate: ``cost`` itself when it is already scaled uint16 and ``inplace``."""
    if cost.dtype == np.uint16 and inplace:
        return cost
    if cost.dtype == np.uint16:
        return cost.copy()
    return cost.astype(np.uint16) * np.uint16(cost_scale)


def mean_lidar_cost(cost, rows, cols, cost_scale):
    """``F_bar`` of the additive walls: the mean plain cost at the LiDAR pixels over all disparities."""
    return float(cost[rows, cols].mean()) / cost_scale if rows.size else 0.0


def _apply(cost, owner, dissim, values, rows, cols, d_min, k, c, band, form, cost_scale, max_cost, wall_scale=None,
           tubes=None):
    if form not in FORMS:
        raise RiverbedError(f"unknown guidance form '{form}' (use additive or product)")
    if wall_scale is None:
        if tubes is not None:
            raise RiverbedError("give wall_scale (F_bar of the walls) for a tube volume")
        wall_scale = mean_lidar_cost(cost, rows, cols, cost_scale)
    flat, W, D, ts, tw, to = volume_layout(cost, owner.shape, tubes)
    _modulate_kernel(flat, W, D, owner, dissim, values, int(d_min), float(k), float(c), float(band), FORMS[form],
                     float(cost_scale), wall_scale, int(max_cost), ts, tw, to)
    return cost


def gauss_modulate(cost, sparse, d_min, k=10.0, c=1.0, form="additive", cost_scale=4, max_cost=65535, inplace=False,
                   wall_scale=None, tubes=None, points=None):
    """Gauss enhancement (paper eq. 5, Poggi et al. 2019) at the LiDAR pixels.

    Parameters
    ----------
    cost : (H, W, D) uint8 or uint16
        Matching cost, ``d = d_min + i`` at index ``i``. A ``uint8`` volume holds plain costs; a ``uint16`` volume
        holds costs already multiplied by ``cost_scale`` (as :func:`census_cost` makes with ``scale``).
    sparse : (H, W) float
        LiDAR disparities of the left image (``d = x_left - x_right``), NaN elsewhere.
    k, c : float
        Height and width (px) of the Gaussian; ``form`` is ``"additive"`` or ``"product"`` (module docstring).
    cost_scale : int
        Fixed-point scale of the output: ``round(cost_scale * cost)`` (scale SGM penalties alike).
    max_cost : int
        Upper bound of guided costs (keeps SGM sums within uint16).
    inplace : bool
        Modulate a scaled ``uint16`` input in place instead of copying it.
    tubes : TubeLayout, optional
        Per-pixel tubes (:class:`~riverbed_cli.matching.volume.TubeLayout`): ``cost`` is then the flat tube volume.
    wall_scale : float, optional
        ``F_bar`` of the additive walls, in plain cost units. Default: the mean cost at the LiDAR pixels
        (:func:`mean_lidar_cost`). A fixed value (the matcher passes half the census bits) makes the result independent
        of which LiDAR points a tile holds; the walls' height barely matters (docs/method.md).
    points : tuple, optional
        ``lidar_points(sparse)`` (rows, columns, disparities) if already found.

    Returns
    -------
    (H, W, D) uint16
        Scaled costs, modulated at the LiDAR pixels and unchanged (times ``cost_scale``) elsewhere.
    """
    check_volume(cost, sparse, tubes)
    rows, cols, values = lidar_points(sparse) if points is None else points
    owner = np.full(sparse.shape, -1, dtype=np.int32)
    owner[rows, cols] = np.arange(rows.size, dtype=np.int32)
    dissim = np.zeros(sparse.shape, dtype=np.float32)
    out = scaled_volume(cost, cost_scale, inplace)
    return _apply(out, owner, dissim, values, rows, cols, d_min, k, c, 0.0, form, cost_scale, max_cost, wall_scale,
                  tubes)


def riverbed_modulate(cost, sparse, guide, d_min, window, k=10.0, c=1.0, sigma_xy=8.0, sigma_i=8.0, gamma=0.3,
                      band=3.0, form="additive", cost_scale=4, max_cost=65535, owners=None, inplace=False,
                      literal_eq3=False, wall_scale=None, tubes=None, points=None):
    """Riverbed enhancement (paper eqs. 2, 3, 6): Gauss at LiDAR pixels, band-and-walls at homogeneous pixels.

    Parameters are those of :func:`gauss_modulate` plus: ``guide`` the left image (0..255 scale) for the colour
    similarity, ``window`` the odd window side ``s``, ``sigma_xy`` (px), ``sigma_i`` (grey levels), ``gamma`` the
    similarity threshold (homogeneous where ``1 - W >= gamma``), and ``band`` the band half-width per unit of ``W``
    (disparity px). ``owners`` may pass a precomputed :func:`homogeneous_owners` result, ``points`` the
    ``lidar_points(sparse)``.

    Returns
    -------
    (H, W, D) uint16
    """
    check_volume(cost, sparse, tubes)
    points = lidar_points(sparse) if points is None else points
    rows, cols, values = points
    if owners is None:
        owners = homogeneous_owners(sparse, guide, window, sigma_xy, sigma_i, gamma, literal_eq3, points)
    owner, dissim = owners
    out = scaled_volume(cost, cost_scale, inplace)
    return _apply(out, owner, dissim, values, rows, cols, d_min, k, c, band, form, cost_scale, max_cost, wall_scale,
                  tubes)
