"""A synthetic but realistic aerial block with exact geometry: the sample data of ``riverbed sample``.

The scene is a 2.5-D surface ``z = f(x, y)`` in a UTM world (EPSG:32632): sloping terrain, roads, houses, flat-roofed
blocks and an industrial hall, trees, a field with crop rows, a parking lot with cars, and a pond, lit by a sun that
casts shadows. Frame cameras fly one line with 60 % along-track overlap; the rectified stereo pair of the first two
exposures is rendered by casting the ray of every pixel onto the surface, airborne LiDAR is simulated as an
oscillating-mirror scanner on a few strips, and the ground truth (the disparity of the pair and a DSM) is written
beside them.

Geometry
--------
- World: EPSG:32632 easting, northing, height (m). All computation happens in *local* coordinates, world minus
  :attr:`Scene.origin` (float64), which is also the pair file's ``origin``.
- The surface is a height field on a regular grid of nodes in a *grid frame* rotated about z by the flight heading,
  interpolated **bilinearly** in each cell. Rays are intersected with it in closed form, found by a two-level grid
  traversal, so a hit point lies on the surface and on its pixel ray by construction.
- Cameras follow the pinhole model with pixel centres at integer coordinates: ``x ~ K R (X - C)``, ``R`` world to
  camera (x right, y down, z forward). The rectified pair shares ``R``; the two principal points differ (a
  Middlebury-style ``doffs``) so that ground disparities are small and positive.
- Ground-truth disparity ``d = x_left - x_right`` of the hit point of each left pixel centre, NaN where that point
  is hidden from the right camera or falls outside the right image.
- Ground-truth DSM: the surface height at the centres of a north-up grid covering the left image's footprint;
  nodata (-9999) elsewhere.

Modules, in the order of the stages
-----------------------------------
- :mod:`.spec`: block sizes (:data:`SIZES`) and the constants every block shares; :mod:`.materials`: materials.
- :mod:`.scene`: the :class:`Scene` (height field, albedo, materials); :mod:`.layout`: building it
  (:func:`build_scene`).
- :mod:`.raycast`: the Numba ray caster and height lookup (:func:`cast_rays`, :func:`surface_height`).
- :mod:`.cameras`: frame cameras, the flight line's exposures, the rectified pair.
- :mod:`.render`: shading, :func:`render_view`, the camera's tone curve and noise, :func:`render_frame`.
- :mod:`.truth`: ground-truth disparity and DSM.
- :mod:`.scan`: the simulated airborne LiDAR scanner.
- :mod:`.block`: :func:`make_block`, the whole block in memory (:class:`Block`).
- :mod:`.write`: the files (``scene.json``, ``MANIFEST.md``, LAZ, raw frames), :func:`write_block`,
  :func:`generate_block`.

Use
---
``riverbed sample OUTDIR [--size small|full] [--seed N]`` or ``python -m riverbed_cli.sample OUTDIR ...`` write a
block (:func:`generate_block`); :func:`make_block` returns it in memory. :func:`render_view` renders any
:class:`FrameCamera`, and :func:`render_frame` the raw, slightly tilted frames of the flight line (their
orientations are in ``scene.json``; :func:`write_block` writes those of the pair to ``raw/`` in the format of
``riverbed rectify``, ``docs/rectify.md``).

Everything is deterministic for a seed. The ray kernels are Numba functions (``cache=True``); the scene itself is
built with numpy and OpenCV resampling. This package does not import the command line (:mod:`riverbed_cli.cli`).
"""

from .block import Block, make_block
from .cameras import FrameCamera, exposures, nadir_rotation, rectified_pair
from .layout import build_scene
from .materials import (CAR, FIELD, GRASS, MATERIAL_CLASS, MATERIAL_DROPOUT, MATERIAL_NAMES, PAVING, ROAD, ROOF,
                        SOIL, SOLAR, TAR, TREE, WATER)
from .raycast import cast_rays, surface_height
from .render import GAIN, expose, render_frame, render_view, shade_points, tone_map
from .scan import materials_at, simulate_scan
from .scene import Scene
from .spec import (CRS, FILES, HEADING, NODATA, ORIGIN, RAW_FRAMES, RAW_PIXEL_SIZE_MM, SIZES, STAGES, SUN_AZIMUTH,
                   SUN_ELEVATION, SizeSpec, exposure_us)
from .truth import ground_truth_disparity, ground_truth_dsm
from .write import generate_block, raw_orientation, scene_description, write_block, write_laz, write_raw_frames

__all__ = [
    # spec
    "CRS", "ORIGIN", "HEADING", "SUN_AZIMUTH", "SUN_ELEVATION", "NODATA", "STAGES", "FILES", "RAW_FRAMES",
    "RAW_PIXEL_SIZE_MM", "SizeSpec", "SIZES", "exposure_us",
    # materials
    "GRASS", "ROAD", "FIELD", "ROOF", "TREE", "WATER", "TAR", "CAR", "SOLAR", "SOIL", "PAVING", "MATERIAL_NAMES",
    "MATERIAL_CLASS", "MATERIAL_DROPOUT",
    # scene, layout, raycast
    "Scene", "build_scene", "cast_rays", "surface_height",
    # cameras
    "FrameCamera", "nadir_rotation", "exposures", "rectified_pair",
    # render
    "GAIN", "shade_points", "tone_map", "render_view", "expose", "render_frame",
    # truth, scan
    "ground_truth_disparity", "ground_truth_dsm", "simulate_scan", "materials_at",
    # block, write
    "Block", "make_block", "scene_description", "write_block", "raw_orientation", "write_raw_frames", "write_laz",
    "generate_block",
]
