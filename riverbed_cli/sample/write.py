"""Writing a block: ``scene.json`` (:func:`scene_description`), ``MANIFEST.md``, the LAZ file (:func:`write_laz`),
the raw frames with their orientation files (:func:`write_raw_frames`), all of them atomically
(:func:`write_block`), and :func:`generate_block` (make and write, with a summary)."""

import datetime
import json
import math
import os
import time
from pathlib import Path

import cv2
import laspy
import numpy as np
import pyproj

from ..errors import RiverbedError
from ..geometry.rectify import orientation_dict, write_orientation
from ..io.atomic import check_output_folder, releases_claims, staging_folder
from ..io.disparity import write_disparity
from ..geometry.pairfile import write_pairfile
from ..io.raster import write_geotiff
from ..products.visualize import write_png
from .block import make_block
from .render import render_frame
from .spec import CRS, FILES, HEADING, NODATA, RAW_FRAMES, RAW_PIXEL_SIZE_MM, SUN_AZIMUTH, SUN_ELEVATION


def _world_matrix(a):
    return [[float(v) for v in row] for row in np.asarray(a)]


def scene_description(block):
    """The contents of ``scene.json``: seed, sun, cameras, LiDAR scanner, DSM grid and scene layout."""
    spec, scene = block.spec, block.scene
    origin = scene.origin
    frames = []
    for k, (cam, att) in enumerate(block.frames):
        frames.append({"id": k, "centre": [float(v) for v in cam.C + origin], "R": _world_matrix(cam.R),
                       "roll_pitch_yaw_deg": list(att), "K": _world_matrix(cam.K), "width": cam.width,
                       "height": cam.height})
    d = block.gt_disparity[np.isfinite(block.gt_disparity)]
    lid = block.lidar
    classes, counts = np.unique(lid["classification"], return_counts=True)
    g = block.dsm_grid
    return {
        "generator": "riverbed sample (riverbed_cli/sample.py)",
        "size": spec.name,
        "seed": block.seed,
        "crs": CRS,
        "origin": [float(v) for v in origin],
        "conventions": "local = world - origin (m); R maps local axes to camera axes (x right, y down, z forward); "
                       "[x, y, 1] ~ K R (X - C); pixel centres at integer coordinates; d = x_left - x_right",
        "sun": {"azimuth_deg": scene.sun_azimuth, "elevation_deg": scene.sun_elevation,
                "direction": [float(v) for v in scene.sun]},
        "flight": {"heading_deg": scene.heading, "flying_height_m": spec.flying_height, "gsd_m": spec.gsd,
                   "focal_px": spec.focal, "overlap": spec.overlap, "baseline_m": spec.baseline},
        "frames": frames,
        "pair": {"frames": [0, 1], "width": block.left_cam.width, "height": block.left_cam.height,
                 "R": _world_matrix(block.left_cam.R), "K_left": _world_matrix(block.left_cam.K),
                 "K_right": _world_matrix(block.right_cam.K), "doffs_px": block.doffs,
                 "baseline_m": float(np.linalg.norm(block.right_cam.C - block.left_cam.C)),
                 "disparity_range_px": [round(float(d.min()), 3), round(float(d.max()), 3)],
                 "gt_valid_share": round(float(np.isfinite(block.gt_disparity).mean()), 5),
                 "occluded_share": round(float(block.occluded.mean()), 5)},
        "lidar": {**lid["info"], "points": len(lid["xyz"]),
                  "classes": {str(int(c)): int(n) for c, n in zip(classes, counts)}},
        "lidar_earlier": {**block.earlier, "points": len(block.lidar_earlier["xyz"]),
                          "definition": "the scan of an earlier epoch: removed_building not yet built (bounds: "
                                        "xmin, ymin, xmax, ymax, m), every point moved by offset_m (east, north, "
                                        "up) from the images' world"},
        "dsm": {"resolution_m": g.resolution, "bounds": [float(v) for v in g.bounds], "width": g.width,
                "height": g.height, "nodata": NODATA,
                "definition": "surface height at cell centres; nodata outside the left image's footprint"},
        "scene": {"cell_m": scene.cell, "nodes": list(scene.height.shape[::-1]),
                  "extent_uv_m": [scene.u0, scene.u0 + (scene.height.shape[1] - 1) * scene.cell, scene.v0,
                                  scene.v0 + (scene.height.shape[0] - 1) * scene.cell],
                  "height_range_m": [round(scene.zlo + origin[2], 3), round(scene.zhi + origin[2], 3)],
                  **scene.layout},
    }


def _bounds(block):
    x0, y0, x1, y1 = block.earlier["removed_building"]["bounds"]
    return f"E {x0:.1f}-{x1:.1f}, N {y0:.1f}-{y1:.1f}"


def _offset(block):
    return ", ".join(f"{v:+g}" for v in block.earlier["offset_m"]) + " m"


def _manifest(block, command):
    spec = block.spec
    W, H = spec.rect_size
    RW, RH = spec.raw_size
    lid = block.lidar
    info = lid["info"]
    g = block.dsm_grid
    d = block.gt_disparity[np.isfinite(block.gt_disparity)]
    ox, oy, oz = (float(v) for v in block.scene.origin)
    B = float(np.linalg.norm(block.right_cam.C - block.left_cam.C))
    return f"""# Synthetic aerial block (size {spec.name}, seed {block.seed})

Generated by

    {command}

(`riverbed_cli/sample.py`; `python -m riverbed_cli.sample OUTDIR` does the same). Deterministic: the same command
regenerates these files, which `tests/test_sample.py` checks. Synthetic data made by this project.

| file | what |
|---|---|
| `left.png`, `right.png` | rectified stereo pair, {W}x{H} RGB 8-bit, rendered by ray casting |
| `pair.yaml` | pair file: `P_left`, `P_right` (world minus `origin` -> pixels), `origin`, `crs` |
| `lidar.laz` | airborne LiDAR, {len(lid["xyz"])} points, LAS 1.4 point format 7 (RGB, GPS time), WKT CRS, 1 mm |
| `lidar_earlier.laz` | the LiDAR of an earlier epoch, {len(block.lidar_earlier["xyz"])} points: before the building at {_bounds(block)} ({block.earlier["removed_building"]["height_m"]:g} m tall) was built, and off the images by {_offset(block)} (east, north, up; `scene.json` `lidar_earlier`) |
| `gt_disparity.tif` | ground-truth disparity of the left image, float32, `d = x_left - x_right`, NaN unknown |
| `gt_dsm.tif` | ground-truth DSM, float32 cloud-optimised GeoTIFF, nodata {NODATA:g} off the left footprint |
| `scene.json` | sun, flight line with the raw frame cameras, rectified cameras, LiDAR scanner, DSM grid, layout |
| `raw/frame0.png`, `raw/frame1.png` | raw (unrectified, slightly tilted) frames of the pair, {RW}x{RH} grey |
| `raw/frame0.yaml`, `raw/frame1.yaml` | their orientations (docs/rectify.md): input of `riverbed rectify` |

## Geometry

- CRS {CRS} (UTM 32N). World = local + origin, origin ({ox:.1f}, {oy:.1f}, {oz:.1f}).
- Pair: frames 0 and 1 of a {spec.exposures}-frame nadir flight line (heading {HEADING:g} deg, {100 * spec.overlap:.0f} %
  overlap), {spec.flying_height:g} m above ground, f = {spec.focal:g} px, GSD {spec.gsd:g} m, baseline {B:.2f} m,
  doffs {block.doffs:g} px (`d = f B / depth + doffs`); GT disparity {d.min():.2f} to {d.max():.2f} px, NaN on
  {100 * (1 - np.isfinite(block.gt_disparity).mean()):.1f} % of the pixels (hidden from the right camera or
  outside the right image).
- GT DSM: {g.resolution:g} m north-up cells, {g.width}x{g.height}, bounds
  ({g.bounds[0]:.1f}, {g.bounds[1]:.1f}, {g.bounds[2]:.1f}, {g.bounds[3]:.1f}); the surface height at cell centres.
- Exact: every pixel's surface point lies on its pixel ray (reprojection and triangulation close to ~1e-12).

## Scene and sensors

Sloping terrain, roads, houses with gable and hip roofs, flat-roofed blocks and an industrial hall (weakly textured
roofs, tar roof patches, skylights, solar panel rows every 2 m), trees, a field with crop rows every 1.6 m, a
parking lot with stall lines and cars, and a pond. Sun at azimuth {SUN_AZIMUTH:g} deg, elevation {SUN_ELEVATION:g}
deg: long, dark cast shadows. Images: 2x2 rays per pixel, 0.5 px optics blur, 1.4-2.7 DN noise; the right image
is exposed 3 % darker. LiDAR: oscillating-mirror zig-zag scan, {info["strips"]} strips at {info["agl_m"]:g} m,
{info["pulse_rate_hz"]:g} Hz pulses, {info["scan_rate_hz"]:g} Hz scan, {info["range_noise_m"]:g} m range noise;
classes 2 ground, 5 high vegetation, 6 building, 9 water, 1 unclassified (cars; outliers: birds, multipath below
ground), 7 low noise; few or no returns on water, tar roofs and solar panels; 40 % of the pulses hitting crowns
also return from the ground beneath (hidden from the cameras).
"""


@releases_claims
def write_block(block, outdir, overwrite=False, command=None):
    """Write a block's files into ``outdir`` (created if missing), all or nothing.

    The files are written into a temporary folder beside ``outdir`` and moved in only once all exist; an existing
    file of the block in ``outdir`` is replaced only with ``overwrite``.

    Returns
    -------
    dict
        File name -> size in bytes.
    """
    outdir = Path(outdir)
    check_output_folder(outdir)
    if outdir.is_dir() and not overwrite:
        present = [f for f in FILES if (outdir / f).exists()]
        if present:
            raise RiverbedError(f"{present[0]} exists; pass --overwrite to replace the block", outdir)
    command = command or f"riverbed sample OUTDIR --size {block.spec.name} --seed {block.seed}"
    check_output_folder(outdir, [f for f in FILES if f != "raw"], overwrite=True)  # locked against another run
    with staging_folder(outdir) as tmp:  # written there, moved in once all exist
        write_png(tmp / "left.png", block.left)
        write_png(tmp / "right.png", block.right)
        write_pairfile(tmp / "pair.yaml", block.pair(tmp),
                       comment=f"Rectified pair of the synthetic aerial block ({command}).")
        write_laz(tmp / "lidar.laz", block.lidar, block.scene.origin)
        write_laz(tmp / "lidar_earlier.laz", block.lidar_earlier, block.scene.origin)
        write_disparity(tmp / "gt_disparity.tif", block.gt_disparity,
                        tags={"riverbed_ground_truth": "disparity d = x_left - x_right (px), NaN unknown",
                              "riverbed_sample": f"{block.spec.name} seed {block.seed}"})
        write_geotiff(tmp / "gt_dsm.tif", block.dsm, block.dsm_grid.transform, crs=CRS, nodata=NODATA,
                      tags={"riverbed_ground_truth": "surface height at cell centres",
                            "riverbed_sample": f"{block.spec.name} seed {block.seed}"})
        text = json.dumps(scene_description(block), indent=1) + "\n"
        (tmp / "scene.json").write_text(text, encoding="utf-8")
        (tmp / "MANIFEST.md").write_text(_manifest(block, command), encoding="utf-8")
        write_raw_frames(block, tmp / "raw", command)
        outdir.mkdir(exist_ok=True)
        if (outdir / "raw").is_dir():  # a folder is not replaced by os.replace: move the old one out first
            os.replace(outdir / "raw", tmp / "raw.old")
        sizes = {}
        for name in FILES:
            os.replace(tmp / name, outdir / name)
            sizes[name] = (outdir / name).stat().st_size
        sizes["raw"] = sum(p.stat().st_size for p in (outdir / "raw").iterdir())
        return sizes


def raw_orientation(block, k):
    """The orientation file contents (``docs/rectify.md``) of raw frame ``k``: the camera that rendered it."""
    cam = block.frames[k][0]
    origin = block.scene.origin
    return orientation_dict(cam.K, cam.R, cam.C + origin, cam.width, cam.height, dist=np.zeros(5), crs=CRS,
                            origin=origin, pixel_size_mm=RAW_PIXEL_SIZE_MM)


def write_raw_frames(block, folder, command=None):
    """Render the raw frames :data:`RAW_FRAMES` (:func:`render_frame`, stored grey to keep the block small)
    into ``folder`` (created) as ``frameK.png``, with their orientation files ``frameK.yaml``."""
    folder = Path(folder)
    folder.mkdir()
    for k in RAW_FRAMES:
        img, _, _ = render_frame(block, k)
        write_png(folder / f"frame{k}.png", cv2.cvtColor(img, cv2.COLOR_RGB2GRAY))
        att = ", ".join(f"{a:g}" for a in block.frames[k][1])
        comment = (f"Raw frame {k} of the synthetic aerial block ({command or 'riverbed sample'}): nadir, "
                   f"roll/pitch/yaw ({att}) deg.\nOrientation file of riverbed rectify (docs/rectify.md); "
                   "omega/phi/kappa: M = R3(kappa) R2(phi) R1(omega).")
        write_orientation(folder / f"frame{k}.yaml", raw_orientation(block, k), comment=comment)


def write_laz(path, lidar, origin, keep=None, crs_3d=False, software="riverbed sample",
              date=datetime.date(2022, 6, 14)):
    """Write simulated LiDAR (:func:`~riverbed_cli.sample.scan.simulate_scan`'s arrays; ``keep``: a mask of the
    points to write, default all) as LAZ (LAS 1.4, point format 7: GPS time and RGB), EPSG:32632 as a WKT VLR
    (``crs_3d``: promoted to 3D, the heights ellipsoidal, as an RPC pair needs).

    Offsets are the minimum rounded down to whole kilometres (heights: to 100 m), scales 1 mm; the header date
    is fixed so the file is reproducible.
    """
    keep = slice(None) if keep is None else keep
    xyz = lidar["xyz"][keep] + np.asarray(origin)
    header = laspy.LasHeader(point_format=7, version="1.4")
    lo = xyz.min(axis=0)
    header.offsets = np.array([math.floor(lo[0] / 1000) * 1000, math.floor(lo[1] / 1000) * 1000,
                               math.floor(lo[2] / 100) * 100], np.float64)
    header.scales = np.array([0.001, 0.001, 0.001])
    crs = pyproj.CRS.from_user_input(CRS)
    header.add_crs(crs.to_3d() if crs_3d else crs)
    header.system_identifier = "riverbed synthetic ALS"
    header.generating_software = software
    header.creation_date = date
    header.global_encoding.gps_time_type = laspy.header.GpsTimeType.STANDARD
    las = laspy.LasData(header)
    las.x, las.y, las.z = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    las.intensity = lidar["intensity"][keep]
    las.return_number = lidar["return_number"][keep]
    las.number_of_returns = lidar["number_of_returns"][keep]
    las.scan_direction_flag = lidar["scan_direction"][keep].astype(np.uint8)
    las.edge_of_flight_line = lidar["edge_of_flight_line"][keep].astype(np.uint8)
    las.classification = lidar["classification"][keep]
    las.scan_angle = np.round(lidar["scan_angle_deg"][keep] / 0.006).astype(np.int16)
    las.point_source_id = lidar["point_source_id"][keep]
    las.gps_time = lidar["gps_time"][keep]
    rgb = lidar["rgb"][keep]
    las.red, las.green, las.blue = rgb[:, 0], rgb[:, 1], rgb[:, 2]
    las.write(str(path), do_compress=True, laz_backend=laspy.LazBackend.Lazrs)


def generate_block(outdir, size="small", seed=0, overwrite=False, command=None, progress=None):
    """Generate a block and write it into ``outdir``; return a summary (files, sizes, timings, key numbers).

    ``command`` is the command line quoted in MANIFEST.md (default ``riverbed sample OUTDIR --size ... --seed
    ...``); ``progress`` is called with each stage name of :data:`STAGES` once it is done.
    """
    t0 = time.perf_counter()
    # Refuse an existing block before spending the time to make a new one.
    outdir = Path(outdir)
    if outdir.is_dir() and not overwrite and any((outdir / f).exists() for f in FILES):
        present = next(f for f in FILES if (outdir / f).exists())
        raise RiverbedError(f"{present} exists; pass --overwrite to replace the block", outdir)
    block = make_block(size, seed, progress)
    t1 = time.perf_counter()
    sizes = write_block(block, outdir, overwrite, command)
    block.seconds["write"] = time.perf_counter() - t1
    if progress:
        progress("write")
    d = block.gt_disparity[np.isfinite(block.gt_disparity)]
    return {
        "outdir": str(outdir), "size": size, "seed": seed, "files": sizes, "bytes": sum(sizes.values()),
        "image": list(block.spec.rect_size), "gsd_m": block.spec.gsd, "crs": CRS,
        "origin": [float(v) for v in block.scene.origin],
        "disparity_range_px": [round(float(d.min()), 3), round(float(d.max()), 3)],
        "lidar_points": len(block.lidar["xyz"]),
        "seconds": {k: round(v, 3) for k, v in {**block.seconds, "total": time.perf_counter() - t0}.items()},
    }
