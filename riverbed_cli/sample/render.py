"""Rendering: sun-and-sky shading with cast shadows (Numba kernels), :func:`render_view` of any frame camera
(supersampled radiance, the exact surface point and material of each pixel centre), water shimmer, the camera's
tone curve and noise (:func:`tone_map`, :func:`expose`), and the raw frames of a block (:func:`render_frame`)."""

import math

import cv2
import numpy as np
from numba import prange

from ..runtime.kernel import kernel
from .cameras import FrameCamera
from .materials import ROOF, SOLAR, TAR, WATER
from .raycast import bilinear, first_hit, locate

# Radiometry: irradiance of the sun (on a surface facing it) and of the sky (RGB, on a horizontal surface).
_E_SUN = 1.0
_E_SKY = np.array([0.085, 0.10, 0.135])
_GAMMA = 1.6  # tone curve of the camera: DN = 255 * (gain * radiance) ** (1 / gamma)
GAIN = 2.7


@kernel
def _shade(pu, pv, pz, hgt, bmax, alb, mat, u0, v0, cell, bs, zlo, zhi, sun, sky, out):
    """Radiance (RGB, linear) of the surface point ``(pu, pv, pz)`` (grid frame) lit by sun and sky.

    Lambertian: ``albedo * (E_sun * max(0, n . s) * lit + E_sky * (0.5 + 0.5 n_z))``; ``lit`` is 0 when a ray
    towards the sun meets the surface (cast shadow). Steep building cells (walls) get a facade pattern.
    Returns the material of the nearest node.
    """
    nv, nu = hgt.shape
    i, j, a, b = locate(pu, pv, nu, nv, u0, v0, cell)
    h00 = float(hgt[j, i])
    h10 = float(hgt[j, i + 1])
    h01 = float(hgt[j + 1, i])
    h11 = float(hgt[j + 1, i + 1])
    e = h00 - h10 - h01 + h11
    gu = (h10 - h00 + e * b) / cell
    gv = (h01 - h00 + e * a) / cell
    norm = math.sqrt(gu * gu + gv * gv + 1.0)
    nx, ny, nz = -gu / norm, -gv / norm, 1.0 / norm
    m = mat[j + (1 if b >= 0.5 else 0), i + (1 if a >= 0.5 else 0)]
    r = bilinear(alb[:, :, 0], i, j, a, b) / 65535.0
    g = bilinear(alb[:, :, 1], i, j, a, b) / 65535.0
    bl = bilinear(alb[:, :, 2], i, j, a, b) / 65535.0
    if nz < 0.35 and (m == ROOF or m == TAR or m == SOLAR):
        # A wall: render stucco with rows of windows (3 m storeys, 2.6 m bays).
        along = pu * ny - pv * nx
        fz = pz - 3.0 * math.floor(pz / 3.0)
        fa = along - 2.6 * math.floor(along / 2.6)
        if 1.0 < fz < 2.4 and 0.7 < fa < 1.9:
            r, g, bl = 0.05, 0.06, 0.08
        else:
            r, g, bl = 0.42, 0.38, 0.32
    ndots = nx * sun[0] + ny * sun[1] + nz * sun[2]
    direct = 0.0
    if ndots > 0.0:
        t = first_hit(pu, pv, pz, sun[0], sun[1], sun[2], 2e-3, np.inf, hgt, bmax, u0, v0, cell, bs, zlo, zhi)
        if t < 0.0:
            direct = ndots
    skyw = 0.5 + 0.5 * nz
    out[0] = r * (_E_SUN * direct + sky[0] * skyw)
    out[1] = g * (_E_SUN * direct + sky[1] * skyw)
    out[2] = bl * (_E_SUN * direct + sky[2] * skyw)
    return m


@kernel(parallel=True)
def _render_kernel(Kinv, Rt, C, ss, cr, sr, hgt, bmax, alb, mat, u0, v0, cell, bs, zlo, zhi, sun, sky, rad, hits,
                   mats):
    height, width = mats.shape
    ogu = cr * C[0] + sr * C[1]
    ogv = -sr * C[0] + cr * C[1]
    for row in prange(height):
        px = np.empty(3)
        for col in range(width):
            acc0 = 0.0
            acc1 = 0.0
            acc2 = 0.0
            for k in range(ss * ss + 1):
                if k == ss * ss:  # the pixel centre: the geometry
                    x, y = float(col), float(row)
                else:
                    x = col - 0.5 + (k % ss + 0.5) / ss
                    y = row - 0.5 + (k // ss + 0.5) / ss
                c0 = Kinv[0, 0] * x + Kinv[0, 1] * y + Kinv[0, 2]
                c1 = Kinv[1, 0] * x + Kinv[1, 1] * y + Kinv[1, 2]
                c2 = Kinv[2, 0] * x + Kinv[2, 1] * y + Kinv[2, 2]
                dx = Rt[0, 0] * c0 + Rt[0, 1] * c1 + Rt[0, 2] * c2
                dy = Rt[1, 0] * c0 + Rt[1, 1] * c1 + Rt[1, 2] * c2
                dz = Rt[2, 0] * c0 + Rt[2, 1] * c1 + Rt[2, 2] * c2
                nrm = math.sqrt(dx * dx + dy * dy + dz * dz)
                dx /= nrm
                dy /= nrm
                dz /= nrm
                du = cr * dx + sr * dy
                dv = -sr * dx + cr * dy
                t = first_hit(ogu, ogv, C[2], du, dv, dz, 0.0, np.inf, hgt, bmax, u0, v0, cell, bs, zlo, zhi)
                if k == ss * ss:
                    if t >= 0.0:
                        hits[row, col, 0] = C[0] + t * dx
                        hits[row, col, 1] = C[1] + t * dy
                        hits[row, col, 2] = C[2] + t * dz
                        i, j, a, b = locate(ogu + t * du, ogv + t * dv, hgt.shape[1], hgt.shape[0], u0, v0, cell)
                        mats[row, col] = mat[j + (1 if b >= 0.5 else 0), i + (1 if a >= 0.5 else 0)]
                    else:
                        hits[row, col, 0] = np.nan
                        hits[row, col, 1] = np.nan
                        hits[row, col, 2] = np.nan
                        mats[row, col] = 255
                elif t >= 0.0:
                    _shade(ogu + t * du, ogv + t * dv, C[2] + t * dz, hgt, bmax, alb, mat, u0, v0, cell, bs, zlo,
                           zhi, sun, sky, px)
                    acc0 += px[0]
                    acc1 += px[1]
                    acc2 += px[2]
                else:  # off the scene: sky-lit haze
                    acc0 += 0.3
                    acc1 += 0.3
                    acc2 += 0.3
            rad[row, col, 0] = acc0 / (ss * ss)
            rad[row, col, 1] = acc1 / (ss * ss)
            rad[row, col, 2] = acc2 / (ss * ss)


@kernel(parallel=True)
def _shade_points_kernel(pts, cr, sr, hgt, bmax, alb, mat, u0, v0, cell, bs, zlo, zhi, sun, sky, rad, mats):
    for n in prange(pts.shape[0]):
        px = np.empty(3)
        pu = cr * pts[n, 0] + sr * pts[n, 1]
        pv = -sr * pts[n, 0] + cr * pts[n, 1]
        mats[n] = _shade(pu, pv, pts[n, 2], hgt, bmax, alb, mat, u0, v0, cell, bs, zlo, zhi, sun, sky, px)
        rad[n, 0] = px[0]
        rad[n, 1] = px[1]
        rad[n, 2] = px[2]


def shade_points(scene, points):
    """Linear RGB radiance and material of surface points (local coordinates), as an orthophoto would see them."""
    pts = np.ascontiguousarray(points, np.float64).reshape(-1, 3)
    rad = np.empty((len(pts), 3))
    mats = np.empty(len(pts), np.uint8)
    c, s = scene.rotation
    _shade_points_kernel(pts, c, s, scene.height, scene.block_max, scene.albedo, scene.material, scene.u0, scene.v0,
                         scene.cell, scene.block, scene.zlo, scene.zhi, scene.sun_grid(), _E_SKY, rad, mats)
    return rad, mats


def tone_map(radiance, gain=GAIN):
    """Camera tone curve: linear radiance to 0..255 floats, ``255 * (gain * L) ** (1 / 1.6)``, clipped."""
    return 255.0 * np.clip(gain * np.asarray(radiance), 0.0, 1.0) ** (1.0 / _GAMMA)


def render_view(scene, camera, supersample=2):
    """Render any frame camera: radiance, and the surface point and material seen at every pixel centre.

    Each pixel's colour is the mean radiance of ``supersample**2`` rays spread over the pixel (box filter); its
    geometry is the ray through the pixel centre, intersected exactly with the surface.

    Returns
    -------
    radiance : (H, W, 3) float64
        Linear radiance (see :func:`tone_map` for the camera's DN).
    hits : (H, W, 3) float64
        Local coordinates of the surface point of each pixel centre (NaN where the ray leaves the scene).
    material : (H, W) uint8
        Material at the hit (255 where none).
    """
    H, W = camera.height, camera.width
    rad = np.empty((H, W, 3))
    hits = np.empty((H, W, 3))
    mats = np.empty((H, W), np.uint8)
    Kinv = np.linalg.inv(camera.K)
    c, s = scene.rotation
    _render_kernel(Kinv, np.ascontiguousarray(camera.R.T), np.ascontiguousarray(camera.C, np.float64),
                   int(supersample), c, s, scene.height, scene.block_max, scene.albedo, scene.material, scene.u0,
                   scene.v0, scene.cell, scene.block, scene.zlo, scene.zhi, scene.sun_grid(), _E_SKY, rad, hits,
                   mats)
    # Water reflects the sky through ripples: a shimmer that differs between viewpoints (matching fails there).
    water = mats == WATER
    if water.any():
        X = hits[water]
        ph = 0.37 * camera.C[0] + 0.61 * camera.C[1]
        rip = (np.sin(2.1 * X[:, 0] + 1.3 * X[:, 1] + ph) + np.sin(-0.9 * X[:, 0] + 2.7 * X[:, 1] + 1.7 * ph)
               + np.sin(3.3 * X[:, 0] - 1.9 * X[:, 1] + 2.3 * ph) + np.sin(0.4 * X[:, 0] + 0.55 * X[:, 1] + ph))
        rad[water] += (0.0035 * (2.0 + 0.5 * rip))[:, None] * np.array([0.8, 0.9, 1.0])
    return rad, hits, mats


def expose(radiance, rng, gain=GAIN, blur=0.5):
    """Camera DN (uint8) of a radiance image: optics blur (Gaussian, ``blur`` px), tone curve, signal-dependent
    noise (1.4-2.7 DN)."""
    if blur:
        radiance = cv2.GaussianBlur(radiance, (0, 0), blur, borderType=cv2.BORDER_REFLECT)
    dn = tone_map(radiance, gain)
    sigma = np.sqrt(2.0 + 0.02 * dn)
    dn = dn + sigma * rng.standard_normal(dn.shape)
    return np.clip(np.round(dn), 0, 255).astype(np.uint8)


def render_frame(block, k, window=None):
    """Render raw (unrectified) frame ``k`` of the block's flight line, as its camera recorded it.

    Parameters
    ----------
    block : Block
    k : int
        Exposure index (``block.frames[k]``: camera and roll/pitch/yaw, also listed in ``scene.json``).
    window : (col0, row0, width, height), optional
        Render only this window of the frame (the camera's principal point shifted accordingly).

    Returns
    -------
    image : (H, W, 3) uint8
        With the same tone curve, optics blur and noise model as the rectified pair (noise seeded by seed and k).
    camera : FrameCamera
        The camera of the rendered window.
    hits : (H, W, 3) float64
        Local coordinates of each pixel centre's surface point.
    """
    cam = block.frames[k][0]
    if window is not None:
        c0, r0, w, h = window
        K = cam.K.copy()
        K[0, 2] -= c0
        K[1, 2] -= r0
        cam = FrameCamera(K, cam.R, cam.C, int(w), int(h))
    rad, hits, _ = render_view(block.scene, cam, block.spec.supersample)
    return expose(rad, np.random.default_rng([block.seed, 20 + k])), cam, hits
