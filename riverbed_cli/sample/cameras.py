"""Frame cameras: the pinhole :class:`FrameCamera`, nadir attitudes, the exposures of the flight line and the
exactly rectified pair of two of them."""

import math
from dataclasses import dataclass

import numpy as np

from .spec import exposure_us


@dataclass(eq=False)
class FrameCamera:
    """A pinhole frame camera: ``[x, y, 1] ~ K R (X - C)`` with ``X`` in local coordinates (world minus origin).

    ``R`` maps local axes to camera axes (x right, y down, z forward, along the optical axis); pixel centres at
    integer coordinates; the image is ``width x height`` pixels.
    """

    K: np.ndarray
    R: np.ndarray
    C: np.ndarray
    width: int
    height: int

    @property
    def P(self):
        """The 3 x 4 projection matrix (local coordinates to pixels)."""
        return self.K @ np.hstack([self.R, (-self.R @ self.C)[:, None]])

    def project(self, X):
        """Pixel coordinates ``(x, y)`` and depth along the optical axis of local points ``X`` (N, 3)."""
        cam = (np.asarray(X, np.float64) - self.C) @ self.R.T
        uvw = cam @ self.K.T
        return uvw[:, 0] / uvw[:, 2], uvw[:, 1] / uvw[:, 2], cam[:, 2]


def _rot(axis, deg):
    a = math.radians(deg)
    c, s = math.cos(a), math.sin(a)
    if axis == 0:
        return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])
    if axis == 1:
        return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def nadir_rotation(heading, attitude=(0.0, 0.0, 0.0)):
    """World-to-camera rotation of a nadir frame camera whose image x axis points along ``heading``.

    ``heading`` in degrees clockwise from north; ``attitude`` = (roll, pitch, yaw) in degrees: small rotations
    of the camera about its own x, y and z axes (applied in that order) away from the ideal nadir orientation.
    """
    a = math.radians(90.0 - heading)
    c, s = math.cos(a), math.sin(a)
    R0 = np.array([[c, s, 0.0], [s, -c, 0.0], [0.0, 0.0, -1.0]])
    roll, pitch, yaw = attitude
    return _rot(2, yaw).T @ _rot(1, pitch).T @ _rot(0, roll).T @ R0


def exposures(scene, spec, seed=0):
    """The nadir frame cameras of the flight line (``spec.exposures`` of them, 60 % along-track overlap).

    Camera centres lie ``spec.flying_height`` above the median scene height; attitudes deviate from the ideal
    nadir by a few tenths of a degree (deterministic for the seed), as a real flight's would.
    """
    rng = np.random.default_rng([seed, 3])
    z = float(np.median(scene.height[::16, ::16])) + spec.flying_height
    z = round(z, 2)
    f = spec.focal
    W, H = spec.raw_size
    K = np.array([[f, 0.0, (W - 1) / 2], [0.0, f, (H - 1) / 2], [0.0, 0.0, 1.0]])
    cams = []
    for u in exposure_us(spec):
        xy = scene.to_local(np.array([u, 0.0]))
        att = tuple(float(a) for a in np.round(rng.normal(0.0, 0.4, 3), 3))
        cams.append((FrameCamera(K.copy(), nadir_rotation(scene.heading, att), np.array([xy[0], xy[1], z]), W, H),
                     att))
    return cams


def rectified_pair(cam_left, cam_right, width, height, doffs):
    """The rectified cameras of two frame cameras: a shared rotation, x along the baseline, z nadir-most.

    Both keep the left camera's focal length; the principal points differ by ``doffs`` px (``cx_left -
    cx_right``), split symmetrically about the image centre, so ``d = f B / depth + doffs``.

    Returns
    -------
    left, right : FrameCamera
    P_left, P_right : (3, 4) float64
        Projection matrices (local coordinates); ``P_right`` is built from ``P_left`` so that rows 2 and 3 are
        identical and row 1 differs by a multiple of row 3 plus the baseline term (an exactly rectified pair).
    """
    Cl, Cr = cam_left.C, cam_right.C
    B = float(np.linalg.norm(Cr - Cl))
    x = (Cr - Cl) / B
    down = np.array([0.0, 0.0, -1.0])
    z = down - (down @ x) * x
    z /= np.linalg.norm(z)
    y = np.cross(z, x)
    R = np.stack([x, y, z])
    f = float(cam_left.K[0, 0])
    cx_l = (width - 1) / 2 + doffs / 2
    cx_r = (width - 1) / 2 - doffs / 2
    cy = (height - 1) / 2
    Kl = np.array([[f, 0.0, cx_l], [0.0, f, cy], [0.0, 0.0, 1.0]])
    Kr = np.array([[f, 0.0, cx_r], [0.0, f, cy], [0.0, 0.0, 1.0]])
    left = FrameCamera(Kl, R, Cl.copy(), width, height)
    right = FrameCamera(Kr, R, Cl + B * x, width, height)
    P_left = left.P
    P_right = P_left.copy()
    P_right[0] = P_left[0] + (cx_r - cx_l) * P_left[2]
    P_right[0, 3] -= f * B
    return left, right, P_left, P_right
