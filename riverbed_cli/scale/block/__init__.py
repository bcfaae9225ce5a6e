"""Blocks: every pair of an aerial block through ``project -> match -> dsm``, merged into one DSM, on dask.distributed.

The manifest (YAML, read with ``yaml.safe_load`` only; paths relative to the manifest's folder)::

    defaults:                  # optional; settings for every pair
      resolution: 0.5          # block-wide (defaults only): DSM cell size in CRS units
      crs: EPSG:32632          # block-wide: CRS of the DSMs and point clouds (default: the pairs')
      agg: max                 # block-wide: per-cell aggregation, max | mean | median | idw
      guide: riverbed          # matching: every setting of `riverbed match` under its name, e.g. matcher
      plus_hops: 2             #   guide window census paths p1 p2 ... adcensus_pi2 diffusion_radius plus_hops
      min_disp: 0              #   min_disp max_disp max_pixels (the table riverbed_cli.matching.config.MATCH_SETTINGS)
      tile: auto               # tiling: tile (px; auto: riverbed match's rule, scale.match_plan.plan_tiles; 0: never)
                               #   overlap lidar_range
      drop_classes: [7, 18]    # projection: outliers visibility side footprint classes drop_classes
                               #             registration (a 4x4 file) lidar_crs
      range_dsm: coarse.tif    # optional: per-pixel ranges from a DSM (GeoTIFF or .hgt) projected into each pair
                               #   as `riverbed project` + `riverbed range-map --window auto` make them (any entry
                               #   kind); range_dsm_margin (px, default 2), range_dsm_crs (the DSM's, if it has none)
    pairs:
      - raw: {left: raw/f0.png, left_orientation: raw/f0.yaml,   # or raw frames with their orientations
              right: raw/f1.png, right_orientation: raw/f1.yaml}   # (riverbed rectify's inputs): rectified into
        cloud: lidar.laz                                           # OUTDIR/pairs/NAME/rectified/ first; optional
                                                                   # alpha (0..1, -1) and size (WxH) as rectify's
      - rpc: {left: l.tif, left_rpc: l.geom,                   # or satellite images and their RPC models
              right: r.tif, right_rpc: r.geom,                     # (riverbed rectify --rpc's inputs): the ROI
              roi: [0, 0, 2000, 2000], dem: srtm.hgt}              # rectified into pairs/NAME/rectified/ by the
        cloud: lidar.laz                                           # project task; optional roi (default the
                                                                   # whole left image), dem or heights ([lo, hi];
                                                                   # neither: the range of the pair's clouds under
                                                                   # the ROI, or without a cloud its tie points),
                                                                   # vertical, pointing (true/false)
      - pair: a/pair.yaml      # a pair file naming the rectified left and right images (or an RPC pair file)
        cloud: lidar/*.laz     # a path, a glob or a list of them (several clouds: per pixel the nearer point);
                               #   none: the images alone, unguided over min_disp..max_disp or the pair file's
                               #   disparity range (riverbed rectify's tie points, an RPC pair's heights)
        name: a                # optional; default the pair file's path without suffix, '/' -> '_' (a_pair)
        range_map: a/ranges.tif  # optional: per-pixel disparity ranges (riverbed match --range-map; pair: entries)
        window: 7              # per-pair override of any setting except the block-wide ones

Outputs (``OUTDIR``)::

    block.json                 marker (the manifest's path) and the record of the last merge
    dsm.tif                    merged DSM of all finished pairs (cloud-optimised GeoTIFF)
    pairs/NAME/sparse.tif      projected LiDAR disparities (pairs with a cloud)
    pairs/NAME/disparity.tif   dense disparity (d = x_left - x_right, NaN invalid)
    pairs/NAME/points.laz      triangulated points, RGB from the left image, CRS
    pairs/NAME/dsm.tif         the pair's DSM, on the block's grid when ``resolution`` is given
    pairs/NAME/done.json       written last: size and sha256 of each output, hash of the settings and inputs

Rules
-----
- *Skipping*: a pair is skipped when its ``done.json`` verifies: every output present with the recorded size and
  sha256, and the recorded hash equal to the hash of the pair's effective settings, its inputs (pair file, images,
  clouds, registration, range map or DSM: path, size, mtime) and the riverbed version. Anything else re-runs the pair.
- *Overwriting*: ``OUTDIR`` may be new (its parent must exist), empty, or the output of the same manifest (its
  ``block.json`` names it); the block then replaces its own files (the per-pair outputs of the pairs it runs, the
  merged DSM, ``block.json``) without ``--overwrite``. A folder holding anything else, or another manifest's
  block, needs ``--overwrite``. Nothing outside ``pairs/NAME/`` of the manifest's pairs, ``dsm.tif`` and
  ``block.json`` is ever written or removed. Every file is written under a temporary name and renamed.
- *Failures*: a pair that fails is reported (name, stage, one-line error) and the others go on; the merged DSM is
  built from the pairs that finished (this run or before). Bad input (:class:`RiverbedError`) is not retried; any
  other exception is retried up to ``retries`` times (dask ``retries``), and a task whose worker died is rerun
  elsewhere up to ``retries`` times (``distributed.scheduler.allowed-failures``, set on the local cluster; an
  existing cluster keeps its scheduler's setting).
- *Interruptions*: a block killed mid-run (its process, or a worker of its cluster) leaves at most temporary files
  (``.STEM.XXXXXXXX.tmp.SUFFIX``, io.atomic's names), image copies in ``pairs/NAME/.work/`` and pairs without a
  ``done.json``. A task redone in the same run removes its own outputs' temporaries before writing; the next run's
  plan removes every temporary file in ``pairs/NAME/`` (and its ``.work/``, ``rectified/``) of the manifest's pairs
  and those of ``dsm.tif`` and ``block.json`` in ``OUTDIR``, and a finished pair's ``.work/`` (killed between its
  ``done.json`` and their removal); it lists them under ``cleaned`` in the summary. Pairs without a verified
  ``done.json`` then run again from their projection; finished pairs are skipped.
- *Merging*: the merged DSM is rasterised from the per-pair LAZ files, streamed in chunks into one
  :class:`~riverbed_cli.products.dsm.Accumulator` on one grid snapped to multiples of the resolution, so every
  aggregation (median and mean included) is exact over the union of the points, not a mosaic of per-pair rasters.
  Its heights are those of the LAZ files (1 mm quantisation). Without ``resolution`` each pair's DSM takes its own
  ground sample distance and the merged DSM the median of those.

RPC pairs (``rpc:`` entries, or ``pair:`` an RPC pair file of ``riverbed rectify --rpc``; docs/rpc.md): the project
task first rectifies the ROI (``rectify`` stage; skipped when ``rectified/inputs.json`` records the same inputs,
ROI, heights and settings), the LiDAR goes through the cloud's CRS and the RPCs, the points are triangulated in
``crs`` (default: the UTM zone of each pair's scene; ``riverbed block split-rpc`` writes one ``crs`` for the
whole scene) with ellipsoidal heights (the DSMs' tag ``riverbed_heights``). The settings hash holds the four files,
the DEM, the clouds and the ROI/heights settings, so changing one ROI re-runs that pair only.

Task graph (dask.distributed, one set per pair to run)::

    project(pair) ──► tile(pair, 0) ──┐
                 ├──► tile(pair, 1) ──┼──► finish(pair)   (stitch, disparity.tif, points.laz, dsm.tif, done.json)
                 └──► ...           ──┘
    all finish ───────────────────────────► merge (OUTDIR/dsm.tif)

``project`` projects the clouds, writes ``sparse.tif`` and plans the matching as
:func:`~riverbed_cli.scale.tiles.match_tiled` would (tile size, ``"auto"`` included, LiDAR tile ranges, one riverbed
window, one 16-bit scale); for a pair larger than the tile it copies the images to ``pairs/NAME/.work/*.npy``. The
client submits every project task at once and, as each one finishes, that pair's tile tasks (they take the project
future as an argument, so the scheduler knows the dependency and recomputes it if its worker dies) and its finish
task (depends on the project and all its tiles). Each tile task reads its crops from disk (memory-mapped images, a
window of ``sparse.tif``) and returns the tile's disparities, computed with the arithmetic of ``match_tiled``'s loop;
a pair no larger than the tile is one task running :func:`~riverbed_cli.matching.pipeline.match_pair` on the whole
images. ``workers=0`` runs the same task functions in order, without dask.

Numba: each task sets its thread's Numba threads to ``CPUs // (workers * threads_per_worker)`` on a local cluster
(on an existing cluster: the worker host's CPUs // the worker's threads). The summary's ``cluster`` holds what the
scheduler reports once the workers are up (``scheduler``, ``workers``, ``threads_per_worker`` per worker, the
``numba_threads`` planned per task), and each pair run now its finish task's ``numba_threads``.
"""

from .manifest import (BLOCK_KEYS, MANIFEST_MAX_BYTES, PAIR_KEYS, RAW_KEYS, RAW_OPTIONS, RPC_KEYS, RPC_OPTIONS,
                       TOP_KEYS, Manifest, PairSpec, default_name, load_manifest)
from .merge import merge_dsm, merge_heights, merge_settings
from .plan import (DONE, MARKER, MERGED, OUTPUTS, RECTIFIED, TEMP_NAME, WORK, BlockPlan, PairJob,
                   clean_pair_leftovers, clean_temps, job_dict, plan_block, prepare_outdir, rectify_raw, rectify_rpc,
                   riverbed_version, rpc_stamp, sha256_file, verify_done, write_json)
from .runner import BlockResult, run_block, task_finish, task_merge, task_project, task_tile
from .settings import SettingError, default_settings, match_params, settings_spec
from .split import MIN_RIGHT_SHARE, split_axis, split_rois, write_split_manifest
from .stages import (PairFailure, PairPlan, RectifyError, finish_stage, n_tasks, project_stage, run_pair,
                     tile_stage)

__all__ = [
    # manifest
    "BLOCK_KEYS", "MANIFEST_MAX_BYTES", "PAIR_KEYS", "RAW_KEYS", "RAW_OPTIONS", "RPC_KEYS", "RPC_OPTIONS", "TOP_KEYS",
    "Manifest", "PairSpec", "default_name", "load_manifest",
    # settings
    "SettingError", "default_settings", "match_params", "settings_spec",
    # planning
    "DONE", "MARKER", "MERGED", "OUTPUTS", "RECTIFIED", "TEMP_NAME", "WORK", "BlockPlan", "PairJob",
    "clean_pair_leftovers", "clean_temps", "job_dict", "plan_block", "prepare_outdir", "rectify_raw", "rectify_rpc",
    "riverbed_version", "rpc_stamp", "sha256_file", "verify_done", "write_json",
    # splitting a satellite scene into ROIs
    "MIN_RIGHT_SHARE", "split_axis", "split_rois", "write_split_manifest",
    # stages
    "PairFailure", "PairPlan", "RectifyError", "finish_stage", "n_tasks", "project_stage", "run_pair",
    "tile_stage",
    # merging
    "merge_dsm", "merge_heights", "merge_settings",
    # running
    "BlockResult", "run_block", "task_finish", "task_merge", "task_project", "task_tile",
]
