"""The merged DSM of a block: the finished pairs' points rasterised onto one grid."""

import statistics
import time
from pathlib import Path

import numpy as np
import rasterio
from pyproj import CRS

from ...errors import RiverbedError
from ...io.lidar import iter_lidar, lidar_info
from ...io.raster import write_geotiff
from ...products.dsm import Accumulator, Grid, close_lattice


def merge_dsm(laz_paths, output, resolution, agg="max", crs=None, chunk_size=1_000_000, heights=None,
              changes=()):
    """Rasterise the points of several LAS/LAZ files onto one grid (snapped to multiples of ``resolution``).

    Chunks stream into one :class:`~riverbed_cli.products.dsm.Accumulator`, so the result is the aggregation over
    the union of the points, exact for every aggregation, its sampling lattice closed (:func:`~riverbed_cli.
    products.dsm_holes.close_lattice`). Writes a COG GeoTIFF (NaN nodata) and returns stats;
    ``heights`` (e.g. ``"ellipsoidal (WGS 84, m)"`` for RPC pairs) goes into its tag ``riverbed_heights``.
    ``changes``: the pairs' change maps (``change.tif``, :mod:`~riverbed_cli.products.change_map`), merged onto the
    same grid (the median of their cells' changes) into ``change.tif`` beside ``output``.
    """
    t0 = time.perf_counter()
    infos = [lidar_info(p) for p in laz_paths]
    infos = [i for i in infos if i.point_count]
    if not infos:
        raise RiverbedError("no points to merge")
    lo = np.min([i.mins for i in infos], axis=0)
    hi = np.max([i.maxs for i in infos], axis=0)
    grid = Grid.from_bounds(lo[0], lo[1], hi[0], hi[1], resolution)
    acc = Accumulator(grid, agg)
    n = 0
    for info in infos:
        for ch in iter_lidar(info.path, chunk_size=chunk_size):
            xyz = ch["xyz"]
            acc.add(xyz[:, 0], xyz[:, 1], xyz[:, 2])
            n += len(xyz)
    dsm = close_lattice(acc.result())[0]  # the image points' sampling lattice, as each pair's DSM closes it
    write_geotiff(output, dsm, grid.transform, crs, float("nan"), None, overwrite=True, band_descriptions=["height"],
                  tags={"riverbed_aggregation": agg, "riverbed_pairs": len(laz_paths),
                        **({"riverbed_heights": heights} if heights else {})})
    out = {"points": n, "resolution": grid.resolution, "width": grid.width, "height": grid.height,
           "bounds": list(grid.bounds), "cells_with_data": float(100.0 * np.isfinite(dsm).mean())}
    if changes:
        out["change_map"] = merge_change(changes, Path(output).parent / "change.tif", grid, crs)
    return {**out, "seconds": round(time.perf_counter() - t0, 4)}


def merge_change(paths, output, grid, crs):
    """The pairs' change maps (GeoTIFFs) merged onto ``grid``: each cell the median of the changes of the pairs'
    cells whose centre falls in it; written to ``output``; returns ``{"pairs", "cells"}``."""
    acc = Accumulator(grid, "median")
    for path in paths:
        with rasterio.open(path) as ds:
            band = ds.read(1)
            rows, cols = np.nonzero(np.isfinite(band))
            x, y = rasterio.transform.xy(ds.transform, rows, cols)
        acc.add(np.asarray(x, np.float64), np.asarray(y, np.float64), band[rows, cols].astype(np.float64))
    change = acc.result()
    write_geotiff(output, change, grid.transform, crs, float("nan"), None, overwrite=True,
                  band_descriptions=["height change (m), match minus LiDAR"], tags={"riverbed_pairs": len(paths)})
    return {"pairs": len(paths), "cells": int(np.isfinite(change).sum())}


def merge_settings(plan, records):
    """Resolution and CRS of the merged DSM from the block's defaults and the finished pairs' records."""
    d = plan.manifest.defaults
    resolution = d["resolution"]
    if resolution is None:
        resolution = float(f"{statistics.median(r['stats']['resolution'] for r in records.values()):.3g}")
    crs = d["crs"]
    if crs is None:
        found = {n: r["stats"].get("crs") for n, r in records.items() if r["stats"].get("crs")}
        if found:
            first_name, first = next(iter(found.items()))
            ref = CRS.from_user_input(first)
            for n, c in found.items():
                if c != first and not CRS.from_user_input(c).equals(ref, ignore_axis_order=True):
                    raise RiverbedError(f"pairs '{first_name}' and '{n}' have different CRSs ({first} vs {c}); "
                                        "give crs under defaults")
            crs = first
    return resolution, crs


def merge_heights(records):
    """What the merged DSM's heights are, from the finished pairs' records: ``"ellipsoidal (WGS 84, m)"`` when
    every pair is an RPC pair, None for pinhole pairs (their world's heights); mixing the two is a
    :class:`RiverbedError`."""
    kinds = {n: r["stats"].get("heights") for n, r in records.items()}
    found = set(kinds.values())
    if len(found) > 1:
        rpc = next(n for n, k in kinds.items() if k)
        other = next(n for n, k in kinds.items() if not k)
        raise RiverbedError(f"pairs '{rpc}' (RPC, {kinds[rpc]} heights) and '{other}' (pinhole) cannot be merged "
                            "into one DSM")
    return found.pop() if found else None
