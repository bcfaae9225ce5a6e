"""A satellite scene split into overlapping ROIs: the block manifest of ``riverbed block split-rpc`` (docs/rpc.md).

A whole Pléiades or WorldView pair (40 000 x 40 000 px) is too large for one affine rectification (the s2p
approximation holds over a few thousand pixels) and for one matching task: :func:`split_rois` tiles the left image
(or a region of it) into ROIs of a given size that overlap by at least a given margin, and
:func:`write_split_manifest` writes one ``rpc:`` pair entry per ROI the right image sees, so ``riverbed block``
rectifies, matches and triangulates each ROI on dask.distributed and merges their points into one DSM.
"""

import math
from pathlib import Path

import yaml

from ...errors import RiverbedError
from ...geometry.rpc_dem import read_dem
from ...geometry.rpc_heights import footprint_bounds, heights_to_ellipsoid
from ...geometry.rpc_pair import MIN_ROI_PX, check_roi, read_rpc_inputs, relative_path, right_share
from ...geometry.rpc_rectify import heights_over_roi
from ...io.atomic import atomic_output

class _NoAliases(yaml.SafeDumper):
    """A safe YAML dumper that writes every entry out in full: the ROIs share their settings' lists (heights,
    clouds), and anchors would tie every ROI to the first one's."""

    def ignore_aliases(self, data):
        return True


#: ROIs the right image sees less of than this share (virtual matches over the height range) are left out.
MIN_RIGHT_SHARE = 0.05


def split_axis(length, size, overlap):
    """Starts (px) of windows of ``size`` covering ``[0, length)`` with consecutive windows sharing at least
    ``overlap`` px, spread evenly (the first at 0, the last ending at ``length``); one window ``[0, length)`` when
    ``length <= size``."""
    if length <= size:
        return [0]
    n = math.ceil((length - overlap) / (size - overlap))
    # floor(i * step) with step = (length - size) / (n - 1) <= size - overlap: consecutive starts differ by at
    # most ceil(step) <= size - overlap, so every overlap is >= overlap px
    return [(i * (length - size)) // (n - 1) for i in range(n)]


def split_rois(region, size, overlap):
    """Overlapping ROIs covering a region of the left image exactly.

    Parameters
    ----------
    region : (col, row, width, height)
        The region to cover (px; the whole image: ``(0, 0, W, H)``).
    size : int or (int, int)
        ROI width and height (px); a region smaller than that along an axis gets one ROI of its own extent there.
    overlap : int
        Pixels shared by neighbouring ROIs at least (0 <= overlap < size).

    Returns
    -------
    list of (col, row, width, height)
        Row-major (top to bottom, left to right); their union is the region, each inside it.
    """
    sw, sh = (size, size) if isinstance(size, int) else size
    x0, y0, w, h = region
    if min(sw, sh) < MIN_ROI_PX:
        raise RiverbedError(f"ROI size must be at least {MIN_ROI_PX} px, got {sw}x{sh}")
    if overlap < 0 or overlap >= min(sw, sh):
        raise RiverbedError(f"overlap must be at least 0 and below the ROI size ({sw}x{sh}), got {overlap}")
    cols = split_axis(w, sw, overlap)
    rows = split_axis(h, sh, overlap)
    return [(x0 + c, y0 + r, min(sw, w), min(sh, h)) for r in rows for c in cols]


def _rel(path, folder):
    return relative_path(path, folder)


def write_split_manifest(output, left, left_rpc, right, right_rpc, clouds, size, overlap, region=None, dem=None,
                         heights=None, vertical=None, pointing=True, crs=None, resolution=None,
                         min_share=MIN_RIGHT_SHARE, overwrite=False):
    """Write a block manifest with one ``rpc:`` pair per ROI of the left image that the right image sees.

    Parameters
    ----------
    output : str or Path
        The manifest (YAML) to write; paths in it are relative to its folder.
    left, left_rpc, right, right_rpc : str or Path
        The satellite images and their RPC models (as ``riverbed rectify --rpc``: any format ``read_rpc`` reads,
        the image itself for GeoTIFF RPC tags; crops of a product are shifted by their offsets).
    clouds : list of str or Path
        LiDAR clouds of every pair (each ROI's project stage reads only clouds whose box reaches it); none: each
        ROI is matched from the images alone, over its range (``dem``, ``heights`` or its tie points).
    size : int or (int, int)
        ROI width and height (px of the left image).
    overlap : int
        Pixels neighbouring ROIs share at least.
    region : (col, row, width, height), optional
        The part of the left image to split (default: all of it).
    dem, heights, vertical, pointing :
        Each ROI's height range (``dem`` a DEM file, ``heights`` ``(lo, hi)`` m; neither: the pair's clouds, or
        without them its tie points) and
        rectification settings, written into every entry.
    crs : str, optional
        The block's CRS (``defaults.crs``); default the UTM zone of the region's centre, so that every ROI's DSM is
        on one grid.
    resolution : float, optional
        The block's DSM cell (m, ``defaults.resolution``); default each pair's ground sample distance.
    min_share : float
        ROIs whose ground the right image sees less than this share of (virtual matches: an 11 x 11 grid over
        the ROI at 5 heights over the range) are left out (and listed in the summary).

    Returns
    -------
    dict
        ``manifest``, ``image`` (W, H), ``region``, ``rois`` (each ``name``, ``roi``, ``right_share``), ``left_out``
        (ROIs the right image does not see enough of), ``heights`` (the range used for that check, m), ``crs``.
    """
    output = Path(output)
    if output.exists() and not overwrite:
        raise RiverbedError("exists; pass --overwrite to replace it", output)
    if not output.absolute().parent.is_dir():
        raise RiverbedError(f"folder {output.absolute().parent} does not exist", output)
    if dem is not None and heights is not None:
        raise RiverbedError("give --dem or --heights (or neither: each ROI's height range from the clouds), not both")
    clouds = [Path(c) for c in clouds or ()]
    for c in clouds:
        if not c.is_file():
            raise RiverbedError("file not found", c)
    (rpc_l, rpc_r), sizes, _ = read_rpc_inputs(left, left_rpc, right, right_rpc)
    W, H = sizes[0]
    region = check_roi((0, 0, W, H) if region is None else region, (W, H), left, option="--region")
    # the height range of the visibility check (and of the scene's centre)
    if heights is not None:
        check = heights_to_ellipsoid(heights, rpc_l, region, vertical)
    elif dem is not None:
        bounds = footprint_bounds(rpc_l, region, rpc_l.height_off)
        d = read_dem(dem, bounds=bounds, vertical=vertical, margin_deg=0.01)
        try:
            check = heights_over_roi(rpc_l, region, d, margin_m=20.0)
        except RiverbedError:
            raise RiverbedError("the DEM does not cover the region's footprint on the terrain", dem) from None
    else:  # the clouds (or tie points) give each ROI's range when it is rectified; here the models' height domain
        check = (rpc_l.height_off - rpc_l.height_scale, rpc_l.height_off + rpc_l.height_scale)
    if crs is None:
        x, y, w, h = region
        lon, lat = rpc_l.localize(x + (w - 1) / 2, y + (h - 1) / 2, 0.5 * (check[0] + check[1]))
        zone = int(math.floor((float(lon) + 180.0) / 6.0)) % 60 + 1
        crs = f"EPSG:{32600 + zone if float(lat) >= 0 else 32700 + zone}"
    folder = output.absolute().parent
    rpc_entry = {"left": _rel(left, folder), "left_rpc": _rel(left_rpc, folder), "right": _rel(right, folder),
                 "right_rpc": _rel(right_rpc, folder)}
    if dem is not None:
        rpc_entry["dem"] = _rel(dem, folder)
    if heights is not None:
        rpc_entry["heights"] = [float(v) for v in heights]
    if vertical is not None:
        rpc_entry["vertical"] = vertical
    if not pointing:
        rpc_entry["pointing"] = False
    cloud = [_rel(c, folder) for c in clouds]
    pairs, kept, left_out = [], [], []
    rois = split_rois(region, size, overlap)
    width = len(str(max(r[1] for r in rois))), len(str(max(r[0] for r in rois)))
    for roi in rois:
        share, _, _ = right_share(rpc_l, rpc_r, roi, check, sizes[1])
        name = f"roi_{roi[1]:0{width[0]}d}_{roi[0]:0{width[1]}d}"  # row, then column: sorts row-major
        item = {"name": name, "roi": list(roi), "right_share": round(share, 4)}
        if share < min_share or share == 0:
            left_out.append(item)
            continue
        kept.append(item)
        entry = {"name": name, "rpc": {**rpc_entry, "roi": list(roi)}}
        if cloud:
            entry["cloud"] = cloud if len(cloud) > 1 else cloud[0]
        pairs.append(entry)
    if not pairs:
        raise RiverbedError(f"the right image sees none of the {len(rois)} ROIs (share of virtual matches inside it "
                            f"below {min_share})", right)
    defaults = {"crs": crs}
    if resolution is not None:
        defaults["resolution"] = float(resolution)
    sw, sh = (size, size) if isinstance(size, int) else size
    comment = (f"Written by riverbed block split-rpc: {Path(left).name} ({W}x{H} px), region "
               f"{','.join(map(str, region))} split into {len(rois)} ROIs of {min(sw, region[2])}x{min(sh, region[3])}"
               f" px overlapping by >= {overlap} px; "
               f"{len(pairs)} seen by {Path(right).name}"
               + (f", {len(left_out)} left out (right image share < {min_share}: "
                  f"{', '.join(i['name'] for i in left_out)})" if left_out else "") + ".\n"
               "Run it: riverbed block THIS.yaml -o OUTDIR [--workers N]")
    text = "".join(f"# {line}\n" for line in comment.splitlines())
    text += yaml.dump({"defaults": defaults, "pairs": pairs}, Dumper=_NoAliases, default_flow_style=None,
                      sort_keys=False, width=120)
    with atomic_output(output, overwrite) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return {"manifest": str(output), "image": [W, H], "region": list(region), "rois": kept, "left_out": left_out,
            "heights": [float(v) for v in check], "crs": crs, "clouds": [str(c) for c in clouds],
            "overlap": int(overlap), "size": [sw, sh],
            "pairs": len(pairs), "min_share": float(min_share)}

