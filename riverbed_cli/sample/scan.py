"""Airborne LiDAR: an oscillating-mirror scanner flown along a few strips (:func:`simulate_scan`), with range
noise, drop-outs on dark and wet materials, last returns from the ground under crowns, and outliers."""

import math

import numpy as np

from .materials import GRASS, MATERIAL_CLASS, MATERIAL_DROPOUT, MATERIAL_NAMES, TREE
from .raycast import cast_rays, surface_height
from .render import shade_points, tone_map


def _bare_height(scene, u, v):
    """Bilinear height of the tree-less coarse surface at grid coordinates (for returns under crowns)."""
    step = scene.cell * scene.tstep
    T = scene.terrain
    fu = np.clip((u - scene.u0) / step, 0, T.shape[1] - 1.000001)
    fv = np.clip((v - scene.v0) / step, 0, T.shape[0] - 1.000001)
    i, j = np.floor(fu).astype(int), np.floor(fv).astype(int)
    a, b = fu - i, fv - j
    return ((1 - a) * (1 - b) * T[j, i] + a * (1 - b) * T[j, i + 1] + (1 - a) * b * T[j + 1, i]
            + a * b * T[j + 1, i + 1])


def simulate_scan(scene, spec, seed=0, range_noise=0.04):
    """Airborne LiDAR of the scene: an oscillating-mirror scanner flown along a few strips.

    Each strip flies parallel to the camera flight line at ``spec.lidar_agl`` m above the median ground, the
    mirror sweeping a zig-zag across the track (``+-spec.lidar_half_fov``); pulse and scan rates give
    ``spec.lidar_density`` pulses per m^2 per strip with equal spacing along and across the track at nadir.
    Strips overlap by a quarter of a swath and are flown in alternate directions; the platform rolls, pitches and
    drifts slightly. Every pulse is a ray cast onto the surface; the return gets Gaussian range noise
    (``range_noise`` m). Dark and wet materials often give no return (:data:`MATERIAL_DROPOUT`). Crowns give a
    second, last return from the ground beneath for 40 % of their pulses. A few outliers are added: birds above
    the scene and multipath returns below the ground, unclassified (class 1), and low-noise points classified 7.

    Returns
    -------
    dict of arrays
        ``xyz`` (N, 3) local coordinates, ``classification``, ``intensity``, ``rgb`` (uint16, the orthophoto
        colour), ``return_number``, ``number_of_returns``, ``gps_time``, ``scan_angle_deg``,
        ``scan_direction``, ``edge_of_flight_line``, ``point_source_id``, ``kind`` (0 surface, 1 ground under
        canopy, 2 unclassified outlier, 3 class-7 noise); and ``info`` (scanner parameters).
    """
    rng = np.random.default_rng([seed, 5])
    ua = scene.u0
    ub = scene.u0 + (scene.height.shape[1] - 1) * scene.cell
    vb = scene.v0 + (scene.height.shape[0] - 1) * scene.cell
    agl, speed = spec.lidar_agl, spec.lidar_speed
    half_fov = math.radians(spec.lidar_half_fov)
    half_swath = agl * math.tan(half_fov)
    spacing = 1.5 * half_swath
    m = max(1, math.ceil(vb / spacing - 0.5 + 1e-9))
    offsets = [(k + 0.5) * spacing for k in range(-m, m)]
    prf = spec.lidar_density * speed * 2 * half_swath
    f_scan = math.sqrt(speed * prf / (8 * half_swath))
    ground = float(np.median(scene.height[::16, ::16]))
    c, s = scene.rotation
    out = {k: [] for k in ("xyz", "mat", "ret", "nret", "time", "angle", "sdir", "edge", "src", "kind", "rng")}
    t_base = 405_000_000.0  # adjusted standard GPS time (GPS seconds - 1e9), June 2022
    for k, v_off in enumerate(offsets):
        forward = k % 2 == 0
        length = ub - ua + 60.0
        n = int(length / speed * prf)
        t = np.arange(n) / prf
        ph = rng.uniform(0, 2 * math.pi, 5)
        along = (ua - 30.0 + speed * t) if forward else (ub + 30.0 - speed * t)
        sgn = 1.0 if forward else -1.0
        x = f_scan * t + ph[0] / (2 * math.pi)
        tri = 4.0 * np.abs(x - np.floor(x + 0.5)) - 1.0  # zig-zag in [-1, 1]
        roll = math.radians(0.15) * np.sin(2 * math.pi * 0.21 * t + ph[1])
        pitch = math.radians(0.1) * np.sin(2 * math.pi * 0.13 * t + ph[2])
        theta = half_fov * tri + roll
        dv_ = np.sin(theta) * np.cos(pitch)
        du_ = sgn * np.sin(pitch)
        dz_ = -np.cos(theta) * np.cos(pitch)
        pv = v_off + 0.8 * np.sin(2 * math.pi * 0.02 * t + ph[3])
        pz = ground + agl + 0.5 * np.sin(2 * math.pi * 0.03 * t + ph[4])
        O = np.stack([c * along - s * pv, s * along + c * pv, pz], axis=1)
        D = np.stack([c * du_ - s * dv_, s * du_ + c * dv_, dz_], axis=1)
        D /= np.linalg.norm(D, axis=1)[:, None]
        th = cast_rays(scene, O, D)
        hit = th >= 0
        O, D, th, t, theta = O[hit], D[hit], th[hit], t[hit], theta[hit]
        sweep_up = np.diff(tri, append=tri[-1])[hit] > 0
        edge = (np.abs(tri) > 1.0 - 4.0 * f_scan / prf)[hit]
        P = O + th[:, None] * D
        mats = materials_at(scene, P)
        keep = rng.random(len(P)) >= MATERIAL_DROPOUT[mats]
        O, D, th, t, theta, P, mats = O[keep], D[keep], th[keep], t[keep], theta[keep], P[keep], mats[keep]
        sweep_up, edge = sweep_up[keep], edge[keep]
        noisy = th + range_noise * rng.standard_normal(len(th))
        first = O + noisy[:, None] * D
        two = (mats == TREE) & (rng.random(len(P)) < 0.4)
        # Last returns from the ground under crowns: continue the ray down to the tree-less surface.
        Og, Dg, tg = O[two], D[two], th[two].copy()
        for _ in range(6):
            Q = Og + tg[:, None] * Dg
            gu, gv = c * Q[:, 0] + s * Q[:, 1], -s * Q[:, 0] + c * Q[:, 1]
            tg += (Q[:, 2] - _bare_height(scene, gu, gv)) / -Dg[:, 2]
        ok = tg > th[two] + 1.5
        idx = np.flatnonzero(two)[ok]
        tg = tg[ok] + range_noise * rng.standard_normal(ok.sum())
        last = O[idx] + tg[:, None] * D[idx]
        nret = np.ones(len(P), np.uint8)
        nret[idx] = 2
        # Interleave: each pulse's returns consecutively, in time order.
        order = np.argsort(np.concatenate([np.arange(len(P)) * 2, idx * 2 + 1]), kind="stable")

        def cat(a, b, order=order):
            return np.concatenate([a, b])[order]

        out["xyz"].append(cat(first, last))
        out["mat"].append(cat(mats, np.full(len(idx), GRASS, np.uint8)))
        out["ret"].append(cat(np.ones(len(P), np.uint8), np.full(len(idx), 2, np.uint8)))
        out["nret"].append(cat(nret, nret[idx]))
        out["time"].append(cat(t, t[idx]) + t_base + 600.0 * k)
        out["angle"].append(np.degrees(cat(theta, theta[idx])))
        out["sdir"].append(cat(sweep_up, sweep_up[idx]))
        out["edge"].append(cat(edge, edge[idx]))
        out["src"].append(np.full(len(P) + len(idx), k + 1, np.uint16))
        out["kind"].append(cat(np.zeros(len(P), np.uint8), np.ones(len(idx), np.uint8)))
        out["rng"].append(cat(noisy, tg))
    pts = {k: np.concatenate(v) for k, v in out.items()}
    n = len(pts["xyz"])
    cls = MATERIAL_CLASS[pts["mat"]].copy()
    cls[pts["kind"] == 1] = 2
    # Outliers: birds (small flocks 20-150 m above ground), multipath (3-15 m below), class-7 low noise.
    n_bird, n_mp, n_noise = max(4, n // 6000), max(4, n // 8000), max(6, n // 3000)
    pick = rng.choice(n, n_bird + n_mp + n_noise, replace=False)
    xyz = pts["xyz"].copy()
    kind = pts["kind"].copy()
    ia, ib, ic = pick[:n_bird], pick[n_bird:n_bird + n_mp], pick[n_bird + n_mp:]
    xyz[ia, 2] += rng.uniform(20, 150, len(ia))
    xyz[ib, 2] -= rng.uniform(3, 15, len(ib))
    xyz[ic, 2] += np.where(rng.random(len(ic)) < 0.8, -rng.uniform(5, 40, len(ic)), rng.uniform(40, 200, len(ic)))
    kind[ia], kind[ib], kind[ic] = 2, 2, 3
    cls[ia], cls[ib], cls[ic] = 1, 1, 7
    # Colour from the orthophoto (sun-lit, shadowed; no camera noise); intensity from the albedo and range.
    surf = pts["xyz"].copy()
    surf[:, 2] = np.nan_to_num(surface_height(scene, surf[:, 0], surf[:, 1]), nan=0.0)
    rad, _ = shade_points(scene, surf)
    rgb = (np.round(tone_map(rad)) * 257).astype(np.uint16)
    alb = _albedo_at(scene, pts["xyz"]).mean(axis=1)
    inten = 65535 * np.clip(2.2 * alb * (agl / pts["rng"]) ** 2, 0, 1) * np.where(pts["nret"] == 2, 0.55, 1.0)
    inten[kind >= 2] *= 0.2
    inten = np.clip(inten * (1 + 0.08 * rng.standard_normal(n)), 0, 65535).astype(np.uint16)
    return {
        "xyz": xyz, "classification": cls, "intensity": inten, "rgb": rgb, "return_number": pts["ret"],
        "number_of_returns": pts["nret"], "gps_time": pts["time"], "scan_angle_deg": pts["angle"],
        "scan_direction": pts["sdir"], "edge_of_flight_line": pts["edge"], "point_source_id": pts["src"],
        "kind": kind,
        "info": {"strips": len(offsets), "strip_offsets_m": [round(o, 3) for o in offsets], "agl_m": agl,
                 "speed_mps": speed, "half_fov_deg": spec.lidar_half_fov, "pulse_rate_hz": round(prf, 1),
                 "scan_rate_hz": round(f_scan, 3), "density_per_strip_m2": spec.lidar_density,
                 "range_noise_m": range_noise, "under_canopy_share": 0.4,
                 "dropout": {MATERIAL_NAMES[i]: float(p) for i, p in enumerate(MATERIAL_DROPOUT) if p > 0},
                 "outliers": {"birds_class1": int(n_bird), "multipath_class1": int(n_mp),
                              "noise_class7": int(n_noise)}},
    }


def _node_index(scene, P):
    c, s = scene.rotation
    u = c * P[:, 0] + s * P[:, 1]
    v = -s * P[:, 0] + c * P[:, 1]
    nv, nu = scene.height.shape
    i = np.clip(np.round((u - scene.u0) / scene.cell).astype(np.int64), 0, nu - 1)
    j = np.clip(np.round((v - scene.v0) / scene.cell).astype(np.int64), 0, nv - 1)
    return j, i


def materials_at(scene, P):
    j, i = _node_index(scene, P)
    return scene.material[j, i]


def _albedo_at(scene, P):
    j, i = _node_index(scene, P)
    return scene.albedo[j, i].astype(np.float64) / 65535.0
