"""A block in memory: :func:`make_block` runs the stages (scene, render, ground truth, LiDAR) and returns a
:class:`Block` (cameras, images, hit points, ground truth, LiDAR arrays)."""

import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import RiverbedError
from ..geometry.cameras import PairGeometry
from .cameras import FrameCamera, exposures, rectified_pair
from .epoch import earlier_lidar
from .layout import build_scene
from .render import GAIN, expose, render_view
from .scan import simulate_scan
from .scene import Scene
from .spec import CRS, SIZES, SizeSpec
from .truth import ground_truth_disparity, ground_truth_dsm


@dataclass(eq=False)
class Block:
    """Everything of a generated block, in memory (what :func:`write_block` puts on disk, and more).

    ``hits_left`` (H, W, 3) are the local coordinates of each left pixel centre's surface point; ``gt_disparity``
    is float64 (the file holds float32); ``occluded`` marks left pixels hidden from the right camera.
    """

    spec: SizeSpec
    seed: int
    scene: Scene
    frames: list  # [(FrameCamera, attitude)] of the flight line
    left_cam: FrameCamera
    right_cam: FrameCamera
    P_left: np.ndarray
    P_right: np.ndarray
    doffs: float
    left: np.ndarray
    right: np.ndarray
    hits_left: np.ndarray
    material_left: np.ndarray
    gt_disparity: np.ndarray
    occluded: np.ndarray
    lidar: dict
    dsm: np.ndarray
    dsm_grid: object
    seconds: dict = field(default_factory=dict)
    lidar_earlier: dict = None  # the LiDAR of an earlier epoch (sample/epoch.py)
    earlier: dict = None  # what differs in it: the building it lacks, its offset

    def pair(self, folder=None):
        """The pair as a :class:`~riverbed_cli.geometry.cameras.PairGeometry` (images in ``folder`` if given)."""
        folder = Path(folder) if folder is not None else None
        return PairGeometry(P_left=self.P_left, P_right=self.P_right, origin=self.scene.origin, crs=CRS,
                            left=folder / "left.png" if folder else None,
                            right=folder / "right.png" if folder else None,
                            width=self.left_cam.width, height=self.left_cam.height)


def make_block(size="small", seed=0, progress=None):
    """Generate a block in memory: scene, cameras, rectified pair, LiDAR and ground truth (deterministic).

    ``progress``, if given, is called with the name of each stage of :data:`STAGES` as it finishes (but the last).
    """
    if size not in SIZES:
        raise RiverbedError(f"unknown size '{size}' (use one of {', '.join(SIZES)})")
    spec = SIZES[size]
    seconds = {}
    done = progress or (lambda stage: None)
    t0 = time.perf_counter()
    scene = build_scene(spec, seed)
    seconds["scene"] = time.perf_counter() - t0
    done("scene")
    frames = exposures(scene, spec, seed)
    W, H = spec.rect_size
    # doffs: the lowest ground in the pair's footprint gets a disparity of about 4 px.
    lo = _footprint_min(scene, W * spec.gsd / 2 + 10, H * spec.gsd / 2 + 10)
    zmax_depth = frames[0][0].C[2] - lo
    doffs = round(4.0 - spec.focal * spec.baseline / zmax_depth, 2)
    left_cam, right_cam, P_left, P_right = rectified_pair(frames[0][0], frames[1][0], W, H, doffs)
    t0 = time.perf_counter()
    rad_l, hits, mats = render_view(scene, left_cam, spec.supersample)
    rad_r, _, _ = render_view(scene, right_cam, spec.supersample)
    left = expose(rad_l, np.random.default_rng([seed, 7]))
    right = expose(rad_r, np.random.default_rng([seed, 8]), gain=GAIN * 0.97)  # a slightly different exposure
    seconds["render"] = time.perf_counter() - t0
    done("render")
    t0 = time.perf_counter()
    disp, occluded = ground_truth_disparity(scene, hits, left_cam, right_cam, P_right)
    dsm, grid = ground_truth_dsm(scene, left_cam, hits, spec.gsd)
    seconds["ground_truth"] = time.perf_counter() - t0
    done("ground_truth")
    t0 = time.perf_counter()
    lidar = simulate_scan(scene, spec, seed)
    # the earlier epoch: a building in the middle of the pair not yet built
    lidar_earlier, earlier = earlier_lidar(scene, spec, seed, W * spec.gsd / 4, H * spec.gsd / 4)
    seconds["lidar"] = time.perf_counter() - t0
    done("lidar")
    return Block(spec, seed, scene, frames, left_cam, right_cam, P_left, P_right, doffs, left, right, hits, mats,
                 disp, occluded, lidar, dsm, grid, seconds, lidar_earlier, earlier)


def _footprint_min(scene, half_u, half_v):
    """Lowest surface height in the grid-frame box ``|u| <= half_u``, ``|v| <= half_v``."""
    i0 = max(int((-half_u - scene.u0) / scene.cell), 0)
    i1 = int((half_u - scene.u0) / scene.cell) + 1
    j0 = max(int((-half_v - scene.v0) / scene.cell), 0)
    j1 = int((half_v - scene.v0) / scene.cell) + 1
    return float(scene.height[j0:j1, i0:i1].min())
