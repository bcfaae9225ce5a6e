"""Building the scene: terrain, roads, houses, halls, apartment blocks, fields, pond, parking lot, cars and trees
painted into node arrays (:class:`_Builder`), the town plan around the main crossing (:func:`_layout` and the
block fillers), and :func:`build_scene`."""

import math

import cv2
import numpy as np

from .materials import CAR, FIELD, GRASS, PAVING, ROAD, ROOF, SOIL, SOLAR, TAR, TREE, WATER
from .scene import Scene
from .spec import HEADING, ORIGIN, SIZES, exposure_us


def _noise(rng, shape, scale):
    """Smooth zero-mean, unit-variance noise of feature size ``scale`` (in nodes) on a ``shape`` array (float32)."""
    scale = max(float(scale), 1.0)
    k = max(round(scale), 1)
    gh, gw = shape[0] // k + 4, shape[1] // k + 4
    g = rng.standard_normal((gh, gw)).astype(np.float32)
    if k == 1:
        return g[:shape[0], :shape[1]].copy()
    big = cv2.resize(g, (gw * k, gh * k), interpolation=cv2.INTER_CUBIC)[k:k + shape[0], k:k + shape[1]]
    return big / np.float32(0.78)  # bicubic interpolation of white noise keeps about 0.78 of its std


def _smoothstep(x, a, b):
    t = np.clip((x - a) / (b - a), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


class _Builder:
    """Paint terrain and objects into node arrays (grid frame)."""

    def __init__(self, spec, extent, rng):
        self.rng = rng
        self.cell = spec.cell
        ua, ub, va, vb = extent
        self.u0, self.v0 = ua, va
        self.nu = math.ceil((ub - ua) / self.cell) + 1
        self.nv = math.ceil((vb - va) / self.cell) + 1
        self.extent = (ua, ua + (self.nu - 1) * self.cell, va, va + (self.nv - 1) * self.cell)
        shape = (self.nv, self.nu)
        self.h = np.zeros(shape, np.float32)
        self.alb = np.zeros(shape + (3,), np.float32)
        self.mat = np.zeros(shape, np.uint8)
        self.objects = {"houses": 0, "flat_buildings": 0, "trees": 0, "cars": 0, "ponds": 0, "fields": 0}
        self.trees = []
        self.tstep = 8
        self.bare = None

    # geometry helpers
    def box(self, ua, ub, va, vb):
        """Node slices covering ``[ua, ub] x [va, vb]`` and the node coordinates there (or None if empty)."""
        i0 = max(math.floor((ua - self.u0) / self.cell), 0)
        i1 = min(math.ceil((ub - self.u0) / self.cell) + 1, self.nu)
        j0 = max(math.floor((va - self.v0) / self.cell), 0)
        j1 = min(math.ceil((vb - self.v0) / self.cell) + 1, self.nv)
        if i0 >= i1 or j0 >= j1:
            return None
        U = (self.u0 + np.arange(i0, i1) * self.cell)[None, :]
        V = (self.v0 + np.arange(j0, j1) * self.cell)[:, None]
        return (slice(j0, j1), slice(i0, i1)), U, V

    def n(self, shape, metres):
        return _noise(self.rng, shape, metres / self.cell)

    def paint(self, sl, mask, colour, material=None, texture=None):
        """Set albedo (``colour`` RGB times ``1 + texture``) and material where ``mask``."""
        a = self.alb[sl]
        col = np.asarray(colour, np.float32)
        val = col[None, None, :] * (1.0 if texture is None else (1.0 + texture)[..., None])
        a[mask] = np.broadcast_to(val, a.shape)[mask]
        if material is not None:
            self.mat[sl][mask] = material

    # the layers
    def terrain(self):
        rng = self.rng
        shape = (self.nv, self.nu)
        U = (self.u0 + np.arange(self.nu) * self.cell)[None, :].astype(np.float32)
        V = (self.v0 + np.arange(self.nv) * self.cell)[:, None].astype(np.float32)
        ang = rng.uniform(0, 2 * math.pi)
        slope = 0.025
        self.h[:] = 40.0 + slope * (math.cos(ang) * U + math.sin(ang) * V)
        self.h += 3.0 * self.n(shape, 70.0) + 0.8 * self.n(shape, 20.0) + 0.08 * self.n(shape, 4.0)
        # Grass: green, patchy, with dry spots; moderate texture at the pixel scale.
        tex = 0.22 * self.n(shape, 6.0) + 0.05 * self.n(shape, 1.2) + 0.03 * self.n(shape, 0.35)
        dry = _smoothstep(self.n(shape, 15.0), 0.6, 1.4)[..., None]
        green = np.array([0.075, 0.11, 0.045], np.float32)
        straw = np.array([0.15, 0.14, 0.085], np.float32)
        self.alb[:] = (green * (1 - dry) + straw * dry) * (1.0 + tex[..., None])
        self.mat[:] = GRASS
        self.slope = (slope, ang)

    def road_u(self, vc, ua, ub, width, dashed=True):
        """A road along u at ``v = vc``: flattened across, asphalt with weak texture, lane markings."""
        r = self.box(ua, ub, vc - width / 2 - 1.5, vc + width / 2 + 1.5)
        if r is None:
            return
        sl, U, V = r
        jc = round((vc - self.v0) / self.cell)
        centre = self.h[jc, sl[1]][None, :]
        d = np.abs(V - vc)
        w = 1.0 - _smoothstep(d, width / 2, width / 2 + 1.5)
        self.h[sl] = self.h[sl] * (1 - w) + centre * w
        self._asphalt(sl, np.broadcast_to(d <= width / 2, self.h[sl].shape), U, V, along=U, across=V - vc,
                      width=width, dashed=dashed)

    def road_v(self, uc, va, vb, width, dashed=True):
        r = self.box(uc - width / 2 - 1.5, uc + width / 2 + 1.5, va, vb)
        if r is None:
            return
        sl, U, V = r
        ic = round((uc - self.u0) / self.cell)
        centre = self.h[sl[0], ic][:, None]
        d = np.abs(U - uc)
        w = 1.0 - _smoothstep(d, width / 2, width / 2 + 1.5)
        w = w * (self.mat[sl] != ROAD)  # junctions: keep the first road's surface
        self.h[sl] = self.h[sl] * (1 - w) + centre * w
        mask = np.broadcast_to(d <= width / 2, self.h[sl].shape) & (self.mat[sl] != ROAD)
        self._asphalt(sl, mask, U, V, along=V, across=U - uc, width=width, dashed=dashed)

    def _asphalt(self, sl, mask, U, V, along, across, width, dashed):
        shape = self.h[sl].shape
        tex = 0.035 * self.n(shape, 0.3) + 0.05 * self.n(shape, 6.0)
        self.paint(sl, mask, (0.085, 0.085, 0.09), ROAD, tex)
        across = np.broadcast_to(across, shape)
        along = np.broadcast_to(along, shape)
        edge = np.abs(np.abs(across) - (width / 2 - 0.35)) < 0.08
        line = edge
        if dashed:
            line = line | ((np.abs(across) < 0.08) & (np.mod(along, 9.0) < 3.0))
        self.paint(sl, mask & line, (0.55, 0.55, 0.53), ROAD, 0.03 * self.n(shape, 0.3))

    def pond(self, uc, vc, ru, rv):
        r = self.box(uc - ru - 3, uc + ru + 3, vc - rv - 3, vc + rv + 3)
        if r is None:
            return
        sl, U, V = r
        q = np.sqrt(((U - uc) / ru) ** 2 + ((V - vc) / rv) ** 2)
        inside = q <= 1.0
        h = self.h[sl]
        level = float(h[inside].min()) - 0.4
        dist = (q - 1.0) * min(ru, rv)  # ~ metres outside the shore
        w = _smoothstep(dist, 0.0, 2.5)
        bank = (~inside) & (dist < 2.5)
        h[:] = np.where(inside, level, np.where(bank, level + 0.15 + (h - level - 0.15) * w, h))
        shape = h.shape
        self.paint(sl, bank, (0.10, 0.09, 0.06), SOIL, 0.15 * self.n(shape, 0.5))
        self.paint(sl, inside, (0.022, 0.036, 0.034), WATER, 0.02 * self.n(shape, 3.0))
        self.objects["ponds"] += 1

    def field(self, ua, ub, va, vb, period=1.6, rows_along_v=True):
        """Crop rows (low ridges, green on brown soil) repeating every ``period`` m."""
        r = self.box(ua, ub, va, vb)
        if r is None:
            return
        sl, U, V = r
        shape = self.h[sl].shape
        coord = np.broadcast_to(U if rows_along_v else V, shape)
        phase = np.cos(2 * math.pi * (coord - ua) / period)
        crop = _smoothstep(phase, -0.2, 0.5)
        crop = crop * (1.0 + 0.06 * self.n(shape, 3.0))
        soil = np.array([0.16, 0.12, 0.08], np.float32)
        green = np.array([0.06, 0.13, 0.04], np.float32)
        tex = 0.02 * self.n(shape, 0.4) + 0.04 * self.n(shape, 5.0)
        col = (soil * (1 - crop[..., None]) + green * crop[..., None]) * (1.0 + tex[..., None])
        self.alb[sl] = col
        self.mat[sl] = FIELD
        self.h[sl] += (0.12 * crop).astype(np.float32)
        self.objects["fields"] += 1

    def paving(self, ua, ub, va, vb, stalls=2.6):
        """A parking lot: asphalt with white stall lines every ``stalls`` m along u, two rows of stalls."""
        r = self.box(ua, ub, va, vb)
        if r is None:
            return
        sl, U, V = r
        shape = self.h[sl].shape
        h = self.h[sl]
        h[:] = float(np.median(h))
        self.paint(sl, np.ones(shape, bool), (0.10, 0.10, 0.10), PAVING,
                   0.03 * self.n(shape, 0.3) + 0.04 * self.n(shape, 4.0))
        vm = 0.5 * (va + vb)
        Ub, Vb = np.broadcast_to(U, shape), np.broadcast_to(V, shape)
        rowband = (np.abs(Vb - vm) > 3.0) & (np.abs(Vb - vm) < 8.0)
        line = rowband & (np.mod(Ub - ua, stalls) < 0.12)
        line |= np.abs(np.abs(Vb - vm) - 3.0) < 0.06
        self.paint(sl, line, (0.6, 0.6, 0.58), PAVING)
        stalls_u = np.arange(ua + stalls / 2, ub - stalls / 2, stalls)
        return [(u, vm + side * 5.5) for u in stalls_u for side in (-1, 1)]

    def building(self, uc, vc, length, width, angle, roof, eave, pitch=35.0, colour=None, material=ROOF,
                 details=True):
        """A building on a rotated rectangle: ``roof`` 'flat', 'gable' (ridge along ``length``) or 'hip'."""
        ca, sa = math.cos(angle), math.sin(angle)
        ext = 0.5 * (abs(length * ca) + abs(width * sa)) + 0.2, 0.5 * (abs(length * sa) + abs(width * ca)) + 0.2
        r = self.box(uc - ext[0], uc + ext[0], vc - ext[1], vc + ext[1])
        if r is None:
            return
        sl, U, V = r
        p = (U - uc) * ca + (V - vc) * sa
        q = -(U - uc) * sa + (V - vc) * ca
        a, b = length / 2, width / 2
        inside = (np.abs(p) <= a) & (np.abs(q) <= b)
        if not inside.any():
            return
        h = self.h[sl]
        base = float(h[inside].max()) + 0.15
        tanp = math.tan(math.radians(pitch))
        if roof == "gable":
            z = base + eave + tanp * (b - np.abs(q))
        elif roof == "hip":
            z = base + eave + tanp * np.minimum(b - np.abs(q), a - np.abs(p))
        else:
            z = np.broadcast_to(base + eave, inside.shape).astype(np.float64)
            if details:  # parapet
                rim = inside & ((a - np.abs(p) < 0.4) | (b - np.abs(q) < 0.4))
                z = np.where(rim, z + 0.6, z)
        h[inside] = np.broadcast_to(z, inside.shape)[inside]
        shape = h.shape
        rng = self.rng
        if colour is None:
            colour = (0.33, 0.32, 0.30)
        if roof == "flat":
            tex = 0.01 * self.n(shape, 0.5) + 0.02 * self.n(shape, 4.0)
        else:  # tiles: faint courses along the slope, each roof side lit differently by the sun
            tex = 0.03 * np.cos(2 * math.pi * np.abs(q) / 0.45) + 0.025 * self.n(shape, 1.5)
        self.paint(sl, inside, colour, material, tex)
        if roof != "flat" and details and rng.random() < 0.6:  # a chimney
            cp, cq = rng.uniform(-a + 1.5, a - 1.5), rng.uniform(0.3, b - 1.5) * rng.choice([-1, 1])
            chim = inside & (np.abs(p - cp) < 0.35) & (np.abs(q - cq) < 0.35)
            if chim.any():
                h[chim] = float(np.broadcast_to(z, shape)[chim].max()) + 1.0
                self.paint(sl, chim, (0.25, 0.12, 0.09), material)
        self.objects["houses" if roof != "flat" else "flat_buildings"] += 1
        return sl, p, q, inside, base + eave

    def roof_units(self, uc, vc, length, width, angle, top, n):
        """``n`` boxes (ventilation units) on a flat roof at height ``top``."""
        rng = self.rng
        for _ in range(n):
            lu, lv = rng.uniform(1.5, 3.5), rng.uniform(1.2, 2.5)
            pu = rng.uniform(-length / 2 + 3, length / 2 - 3)
            pv = rng.uniform(-width / 2 + 3, width / 2 - 3)
            ca, sa = math.cos(angle), math.sin(angle)
            self.box_object(uc + pu * ca - pv * sa, vc + pu * sa + pv * ca, lu, lv, angle, top + rng.uniform(1, 2),
                            (0.45, 0.45, 0.46), ROOF)

    def box_object(self, uc, vc, lu, lv, angle, ztop, colour, material, above_only=True):
        ca, sa = math.cos(angle), math.sin(angle)
        ext = 0.5 * (abs(lu * ca) + abs(lv * sa)) + 0.1, 0.5 * (abs(lu * sa) + abs(lv * ca)) + 0.1
        r = self.box(uc - ext[0], uc + ext[0], vc - ext[1], vc + ext[1])
        if r is None:
            return
        sl, U, V = r
        p = (U - uc) * ca + (V - vc) * sa
        q = -(U - uc) * sa + (V - vc) * ca
        inside = (np.abs(p) <= lu / 2) & (np.abs(q) <= lv / 2)
        h = self.h[sl]
        inside &= h < ztop
        h[inside] = ztop
        self.paint(sl, inside, colour, material, 0.02 * self.n(h.shape, 0.4))

    def car(self, uc, vc, angle):
        rng = self.rng
        r = self.box(uc - 3, uc + 3, vc - 3, vc + 3)
        if r is None:
            return
        sl, _, _ = r
        ground = float(np.median(self.h[sl]))
        palette = [(0.5, 0.5, 0.52), (0.05, 0.05, 0.06), (0.55, 0.08, 0.06), (0.1, 0.15, 0.35), (0.6, 0.6, 0.6),
                   (0.3, 0.3, 0.32)]
        col = palette[rng.integers(len(palette))]
        self.box_object(uc, vc, 4.4, 1.8, angle, ground + 0.85, col, CAR)
        self.box_object(uc + 0.2 * math.cos(angle), vc + 0.2 * math.sin(angle), 2.3, 1.55, angle, ground + 1.45,
                        (0.06, 0.07, 0.08), CAR)
        self.objects["cars"] += 1

    def tree(self, uc, vc, radius, top):
        """Plan a tree (planted by :meth:`plant_trees` once everything else stands)."""
        self.trees.append((uc, vc, radius, top, self.rng.uniform(0.3, 0.45), self.rng.uniform(0.8, 1.25, 3)))

    def plant_trees(self):
        """Keep a coarse copy of the tree-less surface (the ground under the crowns), then paint the trees."""
        self.bare = self.h[::self.tstep, ::self.tstep].copy()
        for args in self.trees:
            self._tree(*args)

    def _tree(self, uc, vc, radius, top, base_share, tint):
        """A tree: an ellipsoidal crown (base at 30-45 % of the top height) with leafy bumps, dark green."""
        r = self.box(uc - radius, uc + radius, vc - radius, vc + radius)
        if r is None:
            return
        sl, U, V = r
        h = self.h[sl]
        ground = float(np.min(h))
        rr = ((U - uc) ** 2 + (V - vc) ** 2) / radius**2
        inside = rr < 1.0
        shape = h.shape
        leaf = self.n(shape, 0.5)
        crown_base = top * base_share
        z = ground + crown_base + (top - crown_base) * np.sqrt(np.clip(1.0 - rr, 0.0, 1.0)) * (1.0 + 0.04 * leaf)
        z = z - 0.15 * np.clip(leaf, 0.0, None) * (1.0 - rr)  # gaps between leaf clusters
        upd = inside & (z > h)
        h[upd] = z[upd]
        tint = np.array([0.045, 0.085, 0.03], np.float32) * tint.astype(np.float32)
        self.paint(sl, upd, tint, TREE, 0.3 * leaf + 0.12 * self.n(shape, 0.25))
        self.objects["trees"] += 1

    def finish(self):
        alb = np.clip(self.alb, 0.0, 1.0)
        return (np.round(alb * 65535.0)).astype(np.uint16)


def _layout(b):
    """Plan and paint the town: roads, then blocks of houses, fields, parks, industry, apartments and forest.

    The four blocks around the main crossing (inside the rectified pair) are fixed in kind so that every
    difficulty appears in the pair: residential (north-west), pond and field (north-east), industrial hall with
    parking lot (south-west), apartment blocks with solar panels and a tar roof (south-east).
    """
    rng = b.rng
    ua, ub, va, vb = b.extent
    vm = -8.0 + rng.uniform(-1, 1)
    road_vs = [vm + k * 78.0 for k in range(-5, 6) if va + 12 < vm + k * 78.0 < vb - 12]
    um = 20.0 + rng.uniform(-2, 2)
    road_us = [um + k * 160.0 for k in range(-8, 9) if ua + 12 < um + k * 160.0 < ub - 12]
    for v in road_vs:
        b.road_u(v, ua, ub, 7.0 if v == vm else 6.0)
    for u in road_us:
        b.road_v(u, va, vb, 6.0)
    # Avenue trees along the main road.
    for side in (-1, 1):
        for u in np.arange(ua + 4, ub - 4, 11.0):
            if min(abs(u - x) for x in road_us) > 8:
                b.tree(u + rng.uniform(-1, 1), vm + side * (3.5 + 3.0), rng.uniform(2.8, 3.8), rng.uniform(9, 13))
    us = [ua] + road_us + [ub]
    vs = [va] + road_vs + [vb]
    kinds = []
    for ki in range(len(us) - 1):
        for kj in range(len(vs) - 1):
            a0 = us[ki] + (3.0 + 3.5 if ki > 0 else 0.0)
            a1 = us[ki + 1] - (3.0 + 3.5 if ki + 1 < len(us) - 1 else 0.0)
            c0 = vs[kj] + (3.5 + 4.0 if kj > 0 else 0.0)
            c1 = vs[kj + 1] - (3.5 + 4.0 if kj + 1 < len(vs) - 1 else 0.0)
            if a1 - a0 < 15 or c1 - c0 < 15:
                continue
            west = us[ki + 1] == um
            east = us[ki] == um
            north = vs[kj] == vm
            south = vs[kj + 1] == vm
            if west and north:
                kind = "residential"
            elif east and north:
                kind = "park_field"
            elif west and south:
                kind = "industrial"
            elif east and south:
                kind = "apartments"
            else:
                kind = ["residential", "field", "forest", "residential", "park_field", "apartments",
                        "industrial"][rng.integers(7)]
            kinds.append(kind)
            low_road, high_road = kj > 0, kj + 1 < len(vs) - 1
            # Face the main road when the block touches it, else a road, else the low edge.
            face = 1.0 if north else -1.0 if south else -1.0 if (high_road and not low_road) else 1.0
            # Put the block's main features next to the main crossing (inside the pair) when it touches it.
            toward = 1.0 if west else -1.0 if east else 0.0
            _FILLERS[kind](b, a0, a1, c0, c1, face, low_road and high_road, toward)
    b.plant_trees()
    return {"main_road_v": vm, "cross_road_u": um, "roads_u": road_vs, "roads_v": road_us, "blocks": kinds}


def _fill_residential(b, a0, a1, c0, c1, face, both_roads, toward):
    """Rows of lots facing the roads: a house each (gable, hip or flat), garden trees, sheds, a car."""
    rng = b.rng
    depth = 28.0
    rows = [(c0, 1.0) if face > 0 else (c1, -1.0)]
    if both_roads and c1 - c0 > 2 * depth:
        rows.append((c1, -1.0) if face > 0 else (c0, 1.0))
    for edge, sgn in rows:
        u = a0 + 1.0
        while u < a1 - 12.0:
            lot = rng.uniform(17.0, 22.0)
            if u + lot > a1:
                break
            L, W = rng.uniform(10.0, 14.0), rng.uniform(8.5, 11.0)
            along_road = rng.random() < 0.7
            angle = (0.0 if along_road else math.pi / 2) + math.radians(rng.uniform(-3, 3))
            uc = u + lot / 2 + rng.uniform(-1.0, 1.0)
            vc = edge + sgn * (6.0 + (W if along_road else L) / 2 + rng.uniform(0, 2))
            kind = rng.choice(["gable", "gable", "hip", "hip", "flat"])
            colour = [(0.30, 0.11, 0.07), (0.26, 0.14, 0.10), (0.13, 0.13, 0.14), (0.34, 0.20, 0.13)][
                rng.integers(4)]
            if kind == "flat":
                b.building(uc, vc, L, W, angle, "flat", rng.uniform(5.5, 7.0), colour=(0.36, 0.35, 0.33))
            else:
                b.building(uc, vc, L, W, angle, kind, rng.uniform(5.0, 6.5), rng.uniform(30, 42), colour)
            if rng.random() < 0.4:
                b.car(uc + sgn * 0.0 + (L / 2 + 3.0), edge + sgn * 4.0, math.pi / 2)
            for _ in range(rng.integers(0, 3)):
                b.tree(u + rng.uniform(3, lot - 3), edge + sgn * rng.uniform(depth - 8, depth - 3),
                       rng.uniform(2.0, 3.8), rng.uniform(6, 12))
            if rng.random() < 0.35:
                b.building(u + rng.uniform(3, lot - 3), edge + sgn * (depth - 4.5), 3.0, 2.5, 0.0, "flat", 2.4,
                           colour=(0.2, 0.18, 0.15), details=False)
            u += lot


def _fill_park_field(b, a0, a1, c0, c1, face, both_roads, toward):
    """A pond with trees near the road, a field with crop rows beyond."""
    rng = b.rng
    edge = c0 if face > 0 else c1
    park = min(30.0, 0.5 * (c1 - c0))
    ru, rv = rng.uniform(12, 16), rng.uniform(6.5, 8.5)
    uc = min(a0 + 12 + ru + rng.uniform(0, 10), a1 - ru - 4)
    vc = edge + face * (2 + rv)
    b.pond(uc, vc, ru, rv)
    for _ in range(rng.integers(8, 14)):
        ang = rng.uniform(0, 2 * math.pi)
        rad = rng.uniform(1.15, 1.8)
        tu, tv = uc + rad * ru * math.cos(ang), vc + rad * rv * math.sin(ang)
        if 2 < face * (tv - edge) < park - 2 and a0 + 3 < tu < a1 - 3:
            b.tree(tu, tv, rng.uniform(2.5, 4.5), rng.uniform(8, 16))
    if c1 - c0 - park > 12:
        lo, hi = (c0 + park, c1) if face > 0 else (c0, c1 - park)
        b.field(a0 + 2, a1 - 2, lo + 2, hi - 2, period=1.6, rows_along_v=True)


def _fill_field(b, a0, a1, c0, c1, face, both_roads, toward):
    b.field(a0 + 2, a1 - 2, c0 + 2, c1 - 2, period=b.rng.choice([1.6, 2.0, 0.9]),
            rows_along_v=bool(b.rng.random() < 0.6))


def _fill_forest(b, a0, a1, c0, c1, face, both_roads, toward):
    rng = b.rng
    for u in np.arange(a0 + 3, a1 - 3, 5.5):
        for v in np.arange(c0 + 3, c1 - 3, 5.5):
            if rng.random() < 0.85:
                b.tree(u + rng.uniform(-2, 2), v + rng.uniform(-2, 2), rng.uniform(2.5, 4.5), rng.uniform(14, 22))


def _fill_industrial(b, a0, a1, c0, c1, face, both_roads, toward):
    """A hall (flat, weakly textured roof, roof units, a tar patch) facing the road, a parking lot beside it."""
    rng = b.rng
    near, sgn = (c0, 1.0) if face > 0 else (c1, -1.0)  # the road the hall faces
    L = min(rng.uniform(44, 55), 0.55 * (a1 - a0))
    W = min(rng.uniform(24, 30), c1 - c0 - 6)
    uc = a1 - 4 - L / 2 if toward > 0 else a0 + 4 + L / 2
    vc = near + sgn * (5.0 + W / 2)
    out = b.building(uc, vc, L, W, 0.0, "flat", rng.uniform(9.0, 11.0), colour=(0.36, 0.36, 0.35))
    if out is not None:
        sl, p, q, inside, top = out
        tar = inside & (np.abs(p - L * 0.22) < L * 0.15) & (np.abs(q + W * 0.1) < W * 0.25)
        b.paint(sl, tar, (0.045, 0.045, 0.05), TAR, 0.02 * b.n(tar.shape, 0.5))
        # Skylight strips: a repetitive pattern across the roof.
        sky = inside & (np.abs(q) < W / 2 - 3) & (np.mod(p + L / 2, 4.0) < 1.0) & (p < -L * 0.1)
        b.paint(sl, sky, (0.55, 0.58, 0.6), ROOF, 0.01 * b.n(sky.shape, 0.5))
        b.roof_units(uc, vc, L, W, 0.0, top, 4)
    span = rng.uniform(34, 42)
    if toward > 0:
        pa0, pa1 = max(a0 + 2, uc - L / 2 - 4 - span), uc - L / 2 - 4
    else:
        pa0, pa1 = uc + L / 2 + 4, min(a1 - 2, uc + L / 2 + 4 + span)
    if pa1 - pa0 > 12:
        pv0 = near + sgn * 2.0
        pv1 = near + sgn * 20.0
        stalls = b.paving(pa0, pa1, min(pv0, pv1), max(pv0, pv1))
        for su, sv in stalls or []:
            if rng.random() < 0.55:
                b.car(su, sv, math.pi / 2 + math.radians(rng.uniform(-3, 3)))


def _fill_apartments(b, a0, a1, c0, c1, face, both_roads, toward):
    """Tall flat-roofed blocks: one with rows of solar panels, one with a dark tar roof; trees between."""
    rng = b.rng
    near, sgn = (c0, 1.0) if face > 0 else (c1, -1.0)
    u = a0 + 6
    k = 0
    while u + 30 < a1 - 4:
        L, W = rng.uniform(32, 42), rng.uniform(12, 15)
        L = min(L, a1 - 4 - u)
        vc = near + sgn * (8.0 + W / 2)
        if toward > 0:  # mirror: start next to the crossing at the block's east end
            u_left = a0 + a1 - u - L
        else:
            u_left = u
        hgt = rng.uniform(15, 20)
        tar = k % 2 == 1
        out = b.building(u_left + L / 2, vc, L, W, 0.0, "flat", hgt, colour=(0.045, 0.045, 0.05) if tar else
                         (0.34, 0.33, 0.31), material=TAR if tar else ROOF)
        if out is not None and not tar:
            sl, p, q, inside, top = out
            # Panel rows (constant-u lines every 2 m): tilted towards the sun, dark blue with bright frames.
            inrow = inside & (np.abs(q) < W / 2 - 1.2) & (np.abs(p) < L / 2 - 1.2)
            ph = np.mod(p + L / 2, 2.0)
            panel = inrow & (ph < 1.2)
            b.h[sl][panel] = (top + 0.15 + 0.35 * np.broadcast_to(ph, panel.shape)[panel]).astype(np.float32)
            b.paint(sl, panel, (0.03, 0.04, 0.08), SOLAR, 0.03 * b.n(panel.shape, 0.5))
            frame = panel & ((ph < 0.08) | (ph > 1.12))
            b.paint(sl, frame, (0.4, 0.4, 0.42), SOLAR)
        for _ in range(rng.integers(2, 5)):
            b.tree(u_left + rng.uniform(0, L), near + sgn * rng.uniform(2.0, 5.0), rng.uniform(2.0, 3.0),
                   rng.uniform(6, 9))
        u += L + rng.uniform(12, 18)
        k += 1


_FILLERS = {"residential": _fill_residential, "park_field": _fill_park_field, "field": _fill_field,
            "forest": _fill_forest, "industrial": _fill_industrial, "apartments": _fill_apartments}


def build_scene(spec, seed=0):
    """Build the scene of a block size (a :class:`SizeSpec` or its name) for a seed.

    The scene covers the nadir footprints of all exposures (at the mean terrain height) plus a 15 m margin, in
    the grid frame centred on the rectified pair.
    """
    spec = SIZES[spec] if isinstance(spec, str) else spec
    rng = np.random.default_rng([seed, 1])
    half_u = spec.raw_size[0] * spec.gsd / 2
    half_v = spec.raw_size[1] * spec.gsd / 2
    us = exposure_us(spec)
    extent = (us[0] - half_u - 15.0, us[-1] + half_u + 15.0, -half_v - 15.0, half_v + 15.0)
    b = _Builder(spec, extent, rng)
    b.terrain()
    layout = _layout(b)
    layout["objects"] = dict(b.objects)
    layout["terrain_slope"] = {"gradient": b.slope[0], "towards_deg_from_u": math.degrees(b.slope[1])}
    # b.bare: the surface without trees every tstep-th node, for LiDAR returns from the ground under crowns.
    return Scene(origin=np.array(ORIGIN), heading=HEADING, u0=b.u0, v0=b.v0, cell=b.cell, height=b.h,
                 albedo=b.finish(), material=b.mat, terrain=b.bare, tstep=b.tstep, layout=layout)
