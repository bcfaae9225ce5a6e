"""A synthetic satellite stereo pair with exact ground truth: ``riverbed sample OUTDIR --satellite``.

The aerial block's scene (:func:`~riverbed_cli.sample.layout.build_scene`: terrain, roads, houses, halls, trees,
fields, a pond, cars; its sun and shadows) is imaged by a **pushbroom** camera from a 650 km orbit, twice along
one pass (a forward and a backward look: along-track stereo, base-to-height ratio about 0.3), at 0.5 m ground
sample distance. RPCs are **fitted** to each camera (:mod:`riverbed_cli.geometry.rpc_fit`) and their fit error
is measured on a separate check grid. The raw (unrectified) images are written as GeoTIFFs with RPC tags, the
ground-truth DSM as a GeoTIFF in the scene's UTM zone with ellipsoidal heights, airborne LiDAR as LAZ at two
densities. :func:`ground_truth_disparity` gives the exact disparity of any rectification of the pair
(``riverbed rectify --rpc``'s ``pair.yaml``), through the rigorous cameras and the scene itself.

Geometry
--------
- The scene's local frame (world minus :data:`~riverbed_cli.sample.spec.ORIGIN`; world = EPSG:32632 easting,
  northing and **heights above the WGS 84 ellipsoid**, m) is taken as Cartesian, and the cameras live in it: a
  line of sight is a straight line in that frame. (Earth curvature over the 300 m scene bends a 650 km line of
  sight by under 1 cm within the scene's 50 m height slab; the synthetic world is defined this way, exactly.)
- **The pushbroom camera** (:class:`PushbroomCamera`): the satellite flies a straight line at
  :attr:`SatelliteSpec.ground_speed` along :attr:`SatelliteSpec.heading`; row ``r`` is read at time ``t = (r -
  (H - 1) / 2) / line_rate`` from the position ``S(t) = S0 + V t``; column ``c`` of the linear CCD looks along
  ``R(t)^T (u(c), v(c), 1)`` with ``u(c) = (c - cc + e s^3) / F``, ``v(c) = b s^2 / F``, ``s = (c - cc) /
  ((W - 1) / 2)``: a cubic across-track distortion of ``e`` px and a CCD line bow of ``b`` px at the edges.
  ``R(t) = exp([a(t)]) R0``, the attitude ``a(t)`` (rad, about the camera's x, y, z axes) a slow drift plus a
  sinusoidal jitter (:attr:`SatelliteSpec.jitter_urad` at :attr:`SatelliteSpec.jitter_hz`), which an RPC cannot
  follow: that jitter is most of the RPC fit error. Pixel centres at integers, ``(0, 0)`` the first pixel's
  centre, as in :mod:`riverbed_cli.geometry.rpc`.
- **Rendering**: each pixel is the mean radiance of ``supersample x supersample`` rays spread over the pixel
  (in column and in row time), cast onto the surface (:func:`~riverbed_cli.sample.raycast.cast_rays`) and shaded
  with sun, sky and cast shadows (:func:`~riverbed_cli.sample.render.shade_points`), water shimmering differently
  in each view; a panchromatic band (the mean of the three channels' radiance) is exposed with the aerial
  camera's tone curve, 0.5 px optics blur and noise (:func:`~riverbed_cli.sample.render.expose`), 8-bit.
- **RPC fit**: a 21 x 21 grid of image points times 7 heights over the scene's height range +- 20 m, localised by
  the rigorous model, converted to WGS 84 by pyproj (EPSG:32632 -> EPSG:4326; heights unchanged: ellipsoidal);
  the check grid: the 20 x 20 cell centres of that grid at the 6 middle heights (also localised).
- **Ground-truth DSM**: the surface height at the centres of a north-up grid of :attr:`SatelliteSpec.gsd` m cells
  (bounds on whole metres), where the cell centre's surface point lies inside both raw images; nodata -9999
  elsewhere.
- **LiDAR**: the aerial block's scanner (:func:`~riverbed_cli.sample.scan.simulate_scan`) at
  :attr:`SatelliteSpec.lidar_density` pulses per m² per strip (``lidar.laz``), and a random thinning of it
  (``lidar_sparse.laz``), LAS 1.4 in EPSG:32632 promoted to 3D (ellipsoidal heights), 1 mm steps.
"""

import json
import math
import os
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import rasterio
from rasterio.errors import NotGeoreferencedWarning
from scipy.spatial.transform import Rotation

from ..errors import RiverbedError
from ..geometry.rpc_rectify import apply_h
from ..io.atomic import check_output_folder, releases_claims, staging_folder
from ..io.raster import write_geotiff
from .layout import build_scene
from .pushbroom import PushbroomCamera, cast_pixels, fit_camera_rpc, render_pushbroom
from .raycast import cast_rays
from .render import GAIN
from .scan import simulate_scan
from .spec import CRS, HEADING, NODATA, SizeSpec
from .truth import ground_truth_dsm
from .write import write_laz

#: the LAZ header's generating software
SOFTWARE = "riverbed sample --satellite"

#: Files of a satellite sample, in the order they are written.
SATELLITE_FILES = ("left.tif", "right.tif", "gt_dsm.tif", "lidar.laz", "lidar_sparse.laz", "scene.json",
                   "MANIFEST.md")
#: Stages of :func:`make_satellite` and :func:`generate_satellite`, in order (for progress reporting).
SATELLITE_STAGES = ("scene", "render", "rpc", "ground_truth", "lidar", "write")
#: Height (local m) the two views aim at, at the scene's centre (the terrain lies about 30 to 70 m local).
AIM_HEIGHT = 45.0
#: Margin (m) of the RPC fit's height range around the scene's.
RPC_HEIGHT_MARGIN = 20.0


@dataclass(frozen=True)
class SatelliteSpec:
    """Parameters of a satellite sample size.

    ``size`` is (width, height) of each raw image (px); ``gsd`` the left image's ground sample distance at the
    scene's centre (m); ``cell`` the scene's node spacing (m); ``altitude`` (m) and ``ground_speed`` (m/s) the
    orbit's; ``heading`` the ground track's direction (degrees clockwise from north: 192 is a descending
    sun-synchronous pass at 45 deg N); ``track_offset`` (m) the ground track's distance from the scene centre
    across track (negative: to the left of the track direction, so the camera looks right); ``along_track_deg``
    the two views' along-track angles (positive forward), left (first) then right; ``yaw_deg`` the CCD lines'
    yaw; ``distortion_px`` / ``bow_px`` the across-track cubic distortion and along-track CCD bow at the edges;
    ``drift_urad_s`` the largest attitude drift rate (µrad/s, drawn per axis and view); ``jitter_urad`` /
    ``jitter_hz`` the attitude jitter; ``lidar_density`` pulses per m² per strip of ``lidar.laz`` and
    ``sparse_share`` the share of its points kept in ``lidar_sparse.laz``.
    """

    name: str
    size: tuple
    gsd: float = 0.5
    cell: float = 0.125
    altitude: float = 650_000.0
    ground_speed: float = 6_800.0
    heading: float = 192.0
    track_offset: float = -30_000.0
    along_track_deg: tuple = (8.0, -10.0)
    yaw_deg: tuple = (0.15, -0.25)
    distortion_px: float = 0.4
    bow_px: float = 0.25
    drift_urad_s: float = 40.0
    jitter_urad: float = 0.05
    jitter_hz: float = 67.0
    supersample: int = 3
    lidar_density: float = 1.5
    sparse_share: float = 0.125

    @property
    def base_to_height(self):
        return sum(abs(math.tan(math.radians(a))) for a in self.along_track_deg)


SATELLITE_SIZES = {
    "small": SatelliteSpec("small", size=(480, 480)),
    "full": SatelliteSpec("full", size=(1200, 1000), cell=0.2),
}


def _axes(heading):
    f = np.array([math.sin(math.radians(heading)), math.cos(math.radians(heading)), 0.0])
    a = np.cross(f, [0.0, 0.0, -1.0])  # image columns: right of the track, seen from above
    return f, a


def satellite_cameras(spec, seed=0):
    """The left (forward-looking, first) and right (backward) pushbroom cameras of a sample size.

    Both views are read from the same straight orbit ``spec.altitude`` m above the aim point (the scene's
    centre at :data:`AIM_HEIGHT`), ``spec.track_offset`` m across track; each points its middle pixel at the aim
    point at its middle row. The focal length gives the left view ``spec.gsd`` across track at the aim point, the
    line rate ``spec.gsd`` along track (flat-Earth ground speed); both views share them (one instrument).
    Attitude drift rates and jitter phases are drawn from the seed.
    """
    rng = np.random.default_rng([seed, 40])
    f, a = _axes(spec.heading)
    X0 = np.array([0.0, 0.0, AIM_HEIGHT])
    W, H = spec.size
    cams = []
    focal = None
    for theta, yaw in zip(spec.along_track_deg, spec.yaw_deg):
        S0 = X0 - spec.altitude * math.tan(math.radians(theta)) * f + spec.track_offset * a \
            + np.array([0.0, 0.0, spec.altitude])
        z = (X0 - S0) / np.linalg.norm(X0 - S0)
        x = a - (a @ z) * z
        x /= np.linalg.norm(x)
        x = Rotation.from_rotvec(math.radians(yaw) * z).apply(x)
        y = np.cross(z, x)
        if focal is None:
            focal = round(float(np.linalg.norm(X0 - S0)) / spec.gsd, 1)
        drift = rng.uniform(-1, 1, 3) * spec.drift_urad_s * 1e-6
        phase = rng.uniform(0, 2 * math.pi, 3)
        cams.append(PushbroomCamera(S0=S0, V=spec.ground_speed * f, R0=np.stack([x, y, z]), focal=focal,
                                    width=W, height=H, line_rate=spec.ground_speed / spec.gsd, drift=drift,
                                    jitter_amp=spec.jitter_urad * 1e-6, jitter_hz=spec.jitter_hz,
                                    jitter_phase=phase, distortion_px=spec.distortion_px, bow_px=spec.bow_px))
    return cams


def scene_spec(spec, cams):
    """The :class:`SizeSpec` whose scene (:func:`build_scene`) covers both images' footprints plus 15 m.

    The footprints are the image corners and edge midpoints localised at local heights 0 and 100 m (the
    terrain's range with room) in the scene's grid frame (heading of the aerial block).
    """
    c, s = math.cos(math.radians(90.0 - HEADING)), math.sin(math.radians(90.0 - HEADING))
    half_u = half_v = 0.0
    for cam in cams:
        W, H = cam.width, cam.height
        cols = np.array([0, (W - 1) / 2, W - 1] * 3, np.float64)
        rows = np.repeat(np.array([0, (H - 1) / 2, H - 1], np.float64), 3)
        for z in (0.0, 100.0):
            X = cam.localize(cols, rows, z)
            half_u = max(half_u, float(np.abs(c * X[:, 0] + s * X[:, 1]).max()))
            half_v = max(half_v, float(np.abs(-s * X[:, 0] + c * X[:, 1]).max()))
    return SizeSpec(f"satellite-{spec.name}", gsd=1.0, flying_height=spec.altitude,
                    raw_size=(math.ceil(2 * half_u), math.ceil(2 * half_v)), overlap=1.0,
                    rect_size=tuple(spec.size), cell=spec.cell, exposures=1, supersample=spec.supersample,
                    lidar_density=spec.lidar_density)


@dataclass(eq=False)
class SatelliteSample:
    """A satellite sample in memory (what :func:`write_satellite` puts on disk, and the scene and cameras).

    ``hits`` are the local surface points of each pixel centre of the two raw images; ``rpc_report`` the fit and
    check errors of each RPC; ``lidar`` the scanner's arrays (:func:`simulate_scan`) and ``sparse`` the mask of
    its points kept in ``lidar_sparse.laz``.
    """

    spec: SatelliteSpec
    seed: int
    scene: object
    cameras: list
    images: list
    hits: list
    rpcs: list
    rpc_report: list
    dsm: np.ndarray
    dsm_grid: object
    lidar: dict
    sparse: np.ndarray
    seconds: dict = field(default_factory=dict)

    @property
    def origin(self):
        return self.scene.origin

    @property
    def height_range(self):
        """The scene's world height range (m, ellipsoidal): what ``riverbed rectify --rpc --heights`` takes."""
        return float(self.scene.zlo + self.origin[2]), float(self.scene.zhi + self.origin[2])


def satellite_scene(size="small", seed=0):
    """The geometry of a satellite sample without its images: ``(spec, scene_spec, cameras, scene)`` (a few
    seconds; what :func:`ground_truth_disparity` needs). ``size`` is a name of :data:`SATELLITE_SIZES` or a
    :class:`SatelliteSpec`."""
    if isinstance(size, SatelliteSpec):
        spec = size
    elif size in SATELLITE_SIZES:
        spec = SATELLITE_SIZES[size]
    else:
        raise RiverbedError(f"unknown size '{size}' (use one of {', '.join(SATELLITE_SIZES)})")
    cams = satellite_cameras(spec, seed)
    sspec = scene_spec(spec, cams)
    return spec, sspec, cams, build_scene(sspec, seed)


def make_satellite(size="small", seed=0, progress=None):
    """Generate a satellite sample in memory (deterministic for a size and seed; ``size`` as for
    :func:`satellite_scene`).

    ``progress``, if given, is called with each stage name of :data:`SATELLITE_STAGES` but the last.
    """
    done = progress or (lambda stage: None)
    seconds = {}
    t0 = time.perf_counter()
    spec, sspec, cams, scene = satellite_scene(size, seed)
    seconds["scene"] = time.perf_counter() - t0
    done("scene")
    t0 = time.perf_counter()
    images, hits = [], []
    for k, cam in enumerate(cams):
        img, hit = render_pushbroom(scene, cam, spec.supersample, np.random.default_rng([seed, 41 + k]),
                                    gain=GAIN * (1.0, 0.97)[k])
        images.append(img)
        hits.append(hit)
    seconds["render"] = time.perf_counter() - t0
    done("render")
    t0 = time.perf_counter()
    oz = float(scene.origin[2])
    heights = (math.floor(scene.zlo + oz - RPC_HEIGHT_MARGIN), math.ceil(scene.zhi + oz + RPC_HEIGHT_MARGIN))
    rpcs, reports = [], []
    for cam in cams:
        rpc, rep = fit_camera_rpc(cam, scene.origin, heights)
        rpcs.append(rpc)
        reports.append(rep)
    seconds["rpc"] = time.perf_counter() - t0
    done("rpc")
    t0 = time.perf_counter()
    dsm, grid = ground_truth_dsm(scene, cams[0], hits[0], spec.gsd)
    gx, gy = np.meshgrid(grid.xmin + (np.arange(grid.width) + 0.5) * grid.resolution - scene.origin[0],
                         grid.ymax - (np.arange(grid.height) + 0.5) * grid.resolution - scene.origin[1])
    valid = dsm != NODATA
    pts = np.stack([gx[valid], gy[valid], dsm[valid].astype(np.float64) - oz], axis=1)
    c, r, _ = cams[1].project(pts)
    inside = (c >= -0.5) & (c < cams[1].width - 0.5) & (r >= -0.5) & (r < cams[1].height - 0.5)
    flat = dsm[valid]
    flat[~inside] = NODATA
    dsm[valid] = flat
    seconds["ground_truth"] = time.perf_counter() - t0
    done("ground_truth")
    t0 = time.perf_counter()
    lidar = simulate_scan(scene, sspec, seed)
    sparse = np.random.default_rng([seed, 43]).random(len(lidar["xyz"])) < spec.sparse_share
    seconds["lidar"] = time.perf_counter() - t0
    done("lidar")
    return SatelliteSample(spec, seed, scene, cams, images, hits, rpcs, reports, dsm, grid, lidar, sparse, seconds)


def ground_truth_disparity(scene, cameras, pair, tolerance=0.01):
    """The exact disparity of a rectification of the sample's pair, through the rigorous cameras and the scene.

    For every pixel centre ``(x, y)`` of the rectified left image, the raw left pixel ``H_left^-1 (x, y)`` is
    cast onto the scene with the left camera's line of sight; the surface point is projected by the right
    camera (:meth:`PushbroomCamera.project`) and through ``H_right``: ``d = x - x_right``. NaN where the raw
    left pixel is outside the left image, the ray misses the scene, the point falls outside the right image, or
    the right camera's line of sight to it meets the surface more than ``tolerance`` m before it (occlusion).

    Parameters
    ----------
    scene : Scene
    cameras : (PushbroomCamera, PushbroomCamera)
        The sample's scene and its left and right cameras (:func:`satellite_scene`, or a
        :class:`SatelliteSample`'s ``scene`` and ``cameras``).
    pair : RPCPair
        The rectified pair (``load_pairfile(path, accept_rpc=True)``), made from the sample's raw images (no
        crop: the RPCs' pixels are the raw images').

    Returns
    -------
    disp : (H, W) float64
        ``d = x_left - x_right`` (px).
    info : dict
        ``valid_share``, ``occluded_share`` (of the rectified pixels), ``row_error_max_px`` / ``_rms_px``
        (right rectified row minus left over the valid pixels: the rectification's own error, from its affine
        model, the RPC fit and the pointing correction), ``d_range``.
    """
    W, H = pair.width, pair.height
    left, right = cameras
    y, x = np.mgrid[0:H, 0:W].astype(np.float64)
    c, r = apply_h(np.linalg.inv(pair.rectification.H_left), x.ravel(), y.ravel())
    disp = np.full(W * H, np.nan)
    occluded = np.zeros(W * H, bool)
    yr = np.full(W * H, np.nan)
    inl = (c >= -0.5) & (c < left.width - 0.5) & (r >= -0.5) & (r < left.height - 0.5)
    idx = np.flatnonzero(inl)
    P = cast_pixels(scene, left, c[idx], r[idx])
    hit = np.isfinite(P[:, 0])
    idx, P = idx[hit], P[hit]
    cr, rr, rng = right.project(P)
    inr = (cr >= -0.5) & (cr < right.width - 0.5) & (rr >= -0.5) & (rr < right.height - 0.5)
    idx, P, cr, rr, rng = idx[inr], P[inr], cr[inr], rr[inr], rng[inr]
    o, _ = right.rays(cr, rr)
    d = (P - o) / rng[:, None]
    tau = (scene.zhi + 1.0 - o[:, 2]) / d[:, 2]
    start = o + tau[:, None] * d
    t = cast_rays(scene, start, d, 0.0, rng - tau + 1.0)
    visible = (t < 0) | (t >= rng - tau - tolerance)
    xr, yrr = apply_h(pair.rectification.H_right, cr, rr)
    disp[idx[visible]] = x.ravel()[idx[visible]] - xr[visible]
    yr[idx[visible]] = yrr[visible]
    occluded[idx[~visible]] = True
    ok = np.isfinite(disp)
    dy = yr[ok] - y.ravel()[ok]
    info = {"valid_share": float(ok.mean()), "occluded_share": float(occluded.mean()),
            "row_error_max_px": float(np.abs(dy).max()) if dy.size else float("nan"),
            "row_error_rms_px": float(np.sqrt(np.mean(dy ** 2))) if dy.size else float("nan"),
            "d_range": [float(np.nanmin(disp)), float(np.nanmax(disp))] if ok.any() else None}
    return disp.reshape(H, W), info


# ---------------------------------------------------------------------------------------------------------------
# writing


def write_rpc_image(path, image, rpc):
    """Write a raw 8-bit image as a GeoTIFF with RPC tags (GDAL's RPC metadata; no geotransform, no CRS)."""
    img = np.asarray(image)
    bands = img[None] if img.ndim == 2 else np.moveaxis(img, -1, 0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NotGeoreferencedWarning)
        with rasterio.open(path, "w", driver="GTiff", width=bands.shape[2], height=bands.shape[1],
                           count=bands.shape[0], dtype=bands.dtype.name, compress="deflate",
                           rpcs=rpc.to_gdal()) as ds:
            ds.write(bands)


def _lidar_density(sample, keep):
    """Points per m² over the ground-truth DSM's valid cells (the pair's common footprint)."""
    g = sample.dsm_grid
    x = sample.lidar["xyz"][keep, 0] + sample.origin[0]
    y = sample.lidar["xyz"][keep, 1] + sample.origin[1]
    i = np.floor((x - g.xmin) / g.resolution).astype(np.int64)
    j = np.floor((g.ymax - y) / g.resolution).astype(np.int64)
    ok = (i >= 0) & (i < g.width) & (j >= 0) & (j < g.height)
    valid = sample.dsm != NODATA
    n = int(valid[j[ok], i[ok]].sum())
    return n / (valid.sum() * g.resolution ** 2)


def satellite_description(sample, command=None):
    """The contents of ``scene.json``: cameras, RPC fit errors, heights, LiDAR, DSM grid and scene layout."""
    spec, scene = sample.spec, sample.scene
    origin = scene.origin
    g = sample.dsm_grid
    lid = sample.lidar
    lo, hi = sample.height_range
    dense = np.ones(len(lid["xyz"]), bool)
    return {
        "generator": "riverbed sample --satellite (riverbed_cli/sample/satellite.py)",
        "command": command,
        "size": spec.name, "seed": sample.seed, "crs": CRS, "crs_heights": "ellipsoidal (WGS 84, m)",
        "origin": [float(v) for v in origin],
        "conventions": "local = world - origin (m), taken as Cartesian; pixel centres at integer (col, row), (0, 0) "
                       "the first pixel's; RPCs: ground WGS 84 lon, lat (deg), ellipsoidal height (m)",
        "orbit": {"altitude_m": spec.altitude, "ground_speed_mps": spec.ground_speed, "heading_deg": spec.heading,
                  "track_offset_m": spec.track_offset, "along_track_deg": list(spec.along_track_deg),
                  "base_to_height": round(spec.base_to_height, 4), "gsd_m": spec.gsd},
        "cameras": {name: cam.to_dict(origin) for name, cam in zip(("left", "right"), sample.cameras)},
        "rpc_fit": {name: rep for name, rep in zip(("left", "right"), sample.rpc_report)},
        "heights_m": [round(lo, 3), round(hi, 3)],
        "lidar": {**lid["info"], "points": int(len(lid["xyz"])), "sparse_points": int(sample.sparse.sum()),
                  "sparse_share": spec.sparse_share,
                  "density_per_m2": round(_lidar_density(sample, dense), 3),
                  "sparse_density_per_m2": round(_lidar_density(sample, sample.sparse), 3)},
        "dsm": {"resolution_m": g.resolution, "bounds": [float(v) for v in g.bounds], "width": g.width,
                "height": g.height, "nodata": NODATA, "valid_cells": int((sample.dsm != NODATA).sum()),
                "definition": "surface height (ellipsoidal) at cell centres seen inside both raw images"},
        "scene": {"cell_m": scene.cell, "nodes": list(scene.height.shape[::-1]), "heading_deg": scene.heading,
                  "height_range_m": [round(lo, 3), round(hi, 3)], **scene.layout},
    }


def _manifest(sample, command, desc):
    spec = sample.spec
    W, H = spec.size
    fl, fr = desc["rpc_fit"]["left"]["check"], desc["rpc_fit"]["right"]["check"]
    lo, hi = desc["heights_m"]
    g = desc["dsm"]
    bounds_txt = " ".join(f"{v:.0f}" for v in g["bounds"])  # whole metres
    lid = desc["lidar"]
    return f"""# Synthetic satellite stereo pair (size {spec.name}, seed {sample.seed})

Generated by

    {command}

(`riverbed_cli/sample/satellite.py`). Deterministic: the same command regenerates these files. Synthetic data made
by this project.

| file | what |
|---|---|
| `left.tif`, `right.tif` | raw pushbroom images, {W}x{H} 8-bit panchromatic, RPC tags (GDAL), no geotransform |
| `gt_dsm.tif` | ground-truth DSM, {CRS}, {g["resolution_m"]:g} m cells, ellipsoidal heights, nodata {NODATA:g} |
| `lidar.laz` | airborne LiDAR, {lid["points"]} points, {lid["density_per_m2"]:g} pt/m² over the pair, {CRS} 3D |
| `lidar_sparse.laz` | {100 * spec.sparse_share:g} % of them at random, {lid["sparse_density_per_m2"]:g} pt/m² |
| `scene.json` | orbit, rigorous cameras, RPC fit errors, heights, LiDAR scanner, DSM grid, scene layout |

## Geometry

- Two views of one pass, {spec.altitude / 1000:g} km up, heading {spec.heading:g} deg, along-track angles
  {spec.along_track_deg[0]:g} deg (left, forward) and {spec.along_track_deg[1]:g} deg (right, backward):
  base-to-height {spec.base_to_height:.3f}; GSD {spec.gsd:g} m. Linear pushbroom cameras with attitude drift
  and {spec.jitter_urad:g} µrad jitter at {spec.jitter_hz:g} Hz, {spec.distortion_px:g} px cubic distortion,
  {spec.bow_px:g} px CCD bow.
- RPCs fitted by least squares on 21x21x7 ground points (heights {desc["rpc_fit"]["left"]["heights_m"]}),
  error on the 20x20x6 check grid: left rms {fl["rms_px"]:.4f} px (max {fl["max_px"]:.4f}), right rms
  {fr["rms_px"]:.4f} px (max {fr["max_px"]:.4f}).
- Scene heights {lo:.2f} to {hi:.2f} m (ellipsoidal).

The whole chain, in this folder (docs/rpc_synthetic.md; `benchmarks/bench_rpc_synthetic.py` runs every method):

```bash
riverbed rectify --rpc left.tif left.tif right.tif right.tif -o rect --heights {math.floor(lo)},{math.ceil(hi)}
riverbed project lidar.laz rect/pair.yaml -o sparse.tif
riverbed match rect/left.tif rect/right.tif --sparse sparse.tif -o disp.tif
riverbed dsm disp.tif rect/pair.yaml -o dsm.tif --bounds {bounds_txt} --resolution {g["resolution_m"]:g}
riverbed evaluate --dsm dsm.tif gt_dsm.tif
```
"""


@releases_claims
def write_satellite(sample, outdir, overwrite=False, command=None):
    """Write a satellite sample's files into ``outdir`` (created if missing), all or nothing.

    Files are written into a temporary folder beside ``outdir`` and moved in once all exist; an existing file of
    the sample in ``outdir`` is replaced only with ``overwrite``. Returns file name -> size in bytes.
    """
    outdir = Path(outdir)
    check_output_folder(outdir)
    _refuse_existing(outdir, overwrite)
    command = command or f"riverbed sample OUTDIR --satellite --size {sample.spec.name} --seed {sample.seed}"
    check_output_folder(outdir, SATELLITE_FILES, overwrite=True)  # locked against another run
    with staging_folder(outdir) as tmp:  # written there, moved in once all exist
        for name, img, rpc in zip(("left.tif", "right.tif"), sample.images, sample.rpcs):
            write_rpc_image(tmp / name, img, rpc)
        tags = {"riverbed_ground_truth": "surface height at cell centres", "riverbed_heights":
                "ellipsoidal (WGS 84, m)", "riverbed_sample": f"satellite {sample.spec.name} seed {sample.seed}"}
        write_geotiff(tmp / "gt_dsm.tif", sample.dsm, sample.dsm_grid.transform, crs=CRS, nodata=NODATA, tags=tags)
        write_laz(tmp / "lidar.laz", sample.lidar, sample.origin, crs_3d=True, software=SOFTWARE)
        write_laz(tmp / "lidar_sparse.laz", sample.lidar, sample.origin, keep=sample.sparse, crs_3d=True,
                  software=SOFTWARE)
        desc = satellite_description(sample, command)
        (tmp / "scene.json").write_text(json.dumps(desc, indent=1) + "\n", encoding="utf-8")
        (tmp / "MANIFEST.md").write_text(_manifest(sample, command, desc), encoding="utf-8")
        outdir.mkdir(exist_ok=True)
        sizes = {}
        for name in SATELLITE_FILES:
            os.replace(tmp / name, outdir / name)
            sizes[name] = (outdir / name).stat().st_size
        return sizes


def _refuse_existing(outdir, overwrite):
    if outdir.is_dir() and not overwrite:
        present = [f for f in SATELLITE_FILES if (outdir / f).exists()]
        if present:
            raise RiverbedError(f"{present[0]} exists; pass --overwrite to replace the sample", outdir)


def generate_satellite(outdir, size="small", seed=0, overwrite=False, command=None, progress=None):
    """Generate a satellite sample and write it into ``outdir``; return a summary (files, sizes, RPC fit errors,
    heights, LiDAR counts, timings). ``progress`` is called with each stage of :data:`SATELLITE_STAGES`."""
    t0 = time.perf_counter()
    outdir = Path(outdir)
    check_output_folder(outdir)
    _refuse_existing(outdir, overwrite)  # before spending the time to make a new one
    sample = make_satellite(size, seed, progress)
    t1 = time.perf_counter()
    sizes = write_satellite(sample, outdir, overwrite, command)
    sample.seconds["write"] = time.perf_counter() - t1
    if progress:
        progress("write")
    lo, hi = sample.height_range
    return {
        "outdir": str(outdir), "kind": "satellite", "size": size, "seed": seed, "files": sizes,
        "bytes": sum(sizes.values()), "image": list(sample.spec.size), "gsd_m": sample.spec.gsd, "crs": CRS,
        "base_to_height": round(sample.spec.base_to_height, 4), "heights_m": [round(lo, 3), round(hi, 3)],
        "rpc_check_rms_px": [round(r["check"]["rms_px"], 5) for r in sample.rpc_report],
        "rpc_check_max_px": [round(r["check"]["max_px"], 5) for r in sample.rpc_report],
        "lidar_points": int(len(sample.lidar["xyz"])), "lidar_sparse_points": int(sample.sparse.sum()),
        "seconds": {k: round(v, 3) for k, v in {**sample.seconds, "total": time.perf_counter() - t0}.items()},
    }
