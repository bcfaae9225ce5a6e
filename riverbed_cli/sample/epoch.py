"""The LiDAR of an earlier epoch (:func:`earlier_lidar`): the same scene scanned before its largest building in the
middle of the pair was built, registered with a small planimetric and height offset. Real LiDAR is older than the
images and off them; this one lets the main job show the LiDAR check and the change map."""

import dataclasses

import cv2
import numpy as np

from .materials import CAR, GRASS, TREE
from .scan import simulate_scan

#: the earlier LiDAR's offset from the images' world (m: east, north, up), as a strip adjustment and another height
#: reference would leave it
EARLIER_OFFSET = (0.15, -0.10, 2.0)


def bare_ground(scene, span=22.0, step=8):
    """The ground without buildings and trees: the surface's morphological opening by a ``span`` m square, on every
    ``step``-th node, interpolated back to every node ((nv, nu) float32; a little low on slopes)."""
    sub = np.ascontiguousarray(scene.height[::step, ::step], np.float32)
    k = max(3, int(round(span / (scene.cell * step))) | 1)
    opened = cv2.morphologyEx(sub, cv2.MORPH_OPEN, np.ones((k, k), np.uint8))
    nv, nu = scene.height.shape
    return cv2.resize(opened, (nu, nv), interpolation=cv2.INTER_LINEAR)


def newest_building(scene, half_u, half_v):
    """The nodes of the largest building within ``|u| <= half_u, |v| <= half_v`` of the grid frame (at least 2.5 m
    above the :func:`bare_ground`, not a tree or a car), grown by two nodes to hold its walls: (nv, nu) bool, the
    ground there, and the building's median height above it (m)."""
    nv, nu = scene.height.shape
    u = scene.u0 + np.arange(nu) * scene.cell
    v = scene.v0 + np.arange(nv) * scene.cell
    U, V = np.meshgrid(u, v)
    ground = bare_ground(scene)
    above = scene.height - ground
    built = ~np.isin(scene.material, (TREE, CAR)) & (above > 2.5) & (np.abs(U) <= half_u) & (np.abs(V) <= half_v)
    n, labels, stats, _ = cv2.connectedComponentsWithStats(built.astype(np.uint8), connectivity=8)
    if n < 2:
        raise ValueError("no building in the middle of the pair")
    k = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
    mask = labels == k
    grown = cv2.dilate(mask.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
    return grown, ground, float(np.median(above[mask])), (U, V)


def earlier_lidar(scene, spec, seed, half_u, half_v):
    """The scan of ``scene`` without its :func:`newest_building`, offset by :data:`EARLIER_OFFSET`: the LiDAR
    arrays (as :func:`~riverbed_cli.sample.scan.simulate_scan`'s) and what differs (``removed_building``: its
    world bounding box and height above the ground, m; ``offset_m``)."""
    grown, ground, height, (U, V) = newest_building(scene, half_u, half_v)
    old = dataclasses.replace(scene, height=np.where(grown, ground, scene.height).astype(np.float32),
                              material=np.where(grown, np.uint8(GRASS), scene.material).astype(np.uint8))
    lidar = simulate_scan(old, spec, seed)
    lidar["xyz"] = lidar["xyz"] + np.asarray(EARLIER_OFFSET)
    corners = scene.to_local(np.stack([U[grown], V[grown]], axis=-1)) + scene.origin[:2]
    box = [float(corners[:, 0].min()), float(corners[:, 1].min()), float(corners[:, 0].max()),
           float(corners[:, 1].max())]
    return lidar, {"removed_building": {"bounds": [round(b, 2) for b in box], "height_m": round(height, 2)},
                   "offset_m": list(EARLIER_OFFSET)}
