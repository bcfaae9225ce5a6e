"""The scene: a height field with albedo and materials in a grid frame rotated by the flight heading
(:class:`Scene`), with the per-block maxima the ray caster skips by."""

import math
from dataclasses import dataclass, field

import numpy as np

from .spec import SUN_AZIMUTH, SUN_ELEVATION


@dataclass(eq=False)
class Scene:
    """A height field with albedo and materials, in a grid frame rotated by the flight heading.

    Node ``(j, i)`` lies at grid coordinates ``(u0 + i * cell, v0 + j * cell)``; grid coordinates relate to local
    ones (world minus ``origin``) by ``u = c x + s y``, ``v = -s x + c y`` with ``(c, s) = (cos, sin)`` of the
    angle from east to the flight direction. Heights are local (world height minus ``origin[2]``).
    """

    origin: np.ndarray
    heading: float
    u0: float
    v0: float
    cell: float
    height: np.ndarray  # (nv, nu) float32
    albedo: np.ndarray  # (nv, nu, 3) uint16, linear reflectance * 65535
    material: np.ndarray  # (nv, nu) uint8
    terrain: np.ndarray  # float32: the surface without trees at every tstep-th node (ground under the crowns)
    tstep: int
    block: int = 16
    block_max: np.ndarray = None
    zlo: float = 0.0
    zhi: float = 0.0
    sun_azimuth: float = SUN_AZIMUTH
    sun_elevation: float = SUN_ELEVATION
    layout: dict = field(default_factory=dict)

    def __post_init__(self):
        h = self.height
        nv, nu = h.shape
        bs = self.block
        nbv, nbu = -(-(nv - 1) // bs), -(-(nu - 1) // bs)
        pad = np.full((nbv * bs + 1, nbu * bs + 1), -np.inf, np.float32)
        pad[:nv, :nu] = h
        core = pad[:-1, :-1].reshape(nbv, bs, nbu, bs).max(axis=(1, 3))
        # Blocks share their edge nodes with the next block.
        edge_u = pad[:-1:, bs::bs].reshape(nbv, bs, nbu).max(axis=1)
        edge_v = pad[bs::bs, :-1].reshape(nbv, nbu, bs).max(axis=2)
        corner = pad[bs::bs, bs::bs]
        self.block_max = np.maximum(np.maximum(core, edge_u), np.maximum(edge_v, corner)).astype(np.float64)
        self.zlo = float(h.min()) - 0.01
        self.zhi = float(h.max()) + 0.01

    @property
    def rotation(self):
        a = math.radians(90.0 - self.heading)
        return math.cos(a), math.sin(a)

    @property
    def sun(self):
        """Unit vector towards the sun, local coordinates (east, north, up)."""
        az, el = math.radians(self.sun_azimuth), math.radians(self.sun_elevation)
        return np.array([math.sin(az) * math.cos(el), math.cos(az) * math.cos(el), math.sin(el)])

    def to_local(self, uv):
        c, s = self.rotation
        uv = np.asarray(uv, np.float64)
        return np.stack([c * uv[..., 0] - s * uv[..., 1], s * uv[..., 0] + c * uv[..., 1]], axis=-1)

    def kernel_args(self):
        c, s = self.rotation
        return (c, s, self.height, self.block_max, self.u0, self.v0, self.cell, self.block, self.zlo, self.zhi)

    def sun_grid(self):
        c, s = self.rotation
        sx, sy, sz = self.sun
        return np.array([c * sx + s * sy, -s * sx + c * sy, sz])
