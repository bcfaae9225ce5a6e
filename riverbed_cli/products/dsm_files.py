"""DSMs from files to files: the disparity maps and pair files a DSM is made of read and checked, and a DSM's
products written together (GeoTIFF, point cloud, change map, hillshade).

``riverbed dsm`` is :func:`read_couples`, :func:`dsm_crs`, :func:`~riverbed_cli.products.dsm.build_dsm` and
:func:`write_dsm_outputs`; a block's pair (``scale/block/stages.py``) is the last two on its stitched disparity.
"""

import numpy as np

from ..errors import RiverbedError
from ..geometry.pairfile import load_pairfile
from ..geometry.rpc_geometry import output_crs
from ..io.atomic import output_group
from ..io.disparity import read_disparity
from ..io.images import read_image
from ..io.lidar import lidar_info, resolve_crs
from ..io.pointcloud import write_points
from ..io.raster import write_geotiff
from .change_map import change_map, read_lidar_mask
from .dsm import hillshade, read_confidence
from .visualize import hillshade_picture, write_picture

#: the DSM's tags: how its cells are made (``riverbed dsm``)
MERGE_RULE = "lidar wins where both exist"
#: the heights of an RPC pair's points and DSMs
RPC_HEIGHTS = "ellipsoidal (WGS 84, m)"


def read_couples(disp_pair, confidences=(), sparses=(), masks=()):
    """Read ``disp_pair`` (disparity map, pair file, ...) and what goes with each couple, checking sizes.

    Returns ``(sources, confidences, changes)``: ``sources`` the ``(disp, pair, left image or None)`` of
    :func:`~riverbed_cli.products.dsm.build_dsm`; ``confidences`` one (H, W) map per couple (Nones without
    ``confidences``); ``changes`` the ``(disp, sparse, mask, pair)`` of
    :func:`~riverbed_cli.products.change_map.change_map` (empty without ``sparses``). Raises
    :class:`RiverbedError` naming the file on a bad or mismatched one.
    """
    sources, confs, changes = [], [], []
    for i, (disp_path, pair_path) in enumerate(zip(disp_pair[::2], disp_pair[1::2])):
        pair = load_pairfile(pair_path, accept_rpc=True, command="riverbed dsm")
        disp = read_disparity(disp_path)
        if pair.image_size is not None and pair.image_size != disp.shape:
            raise RiverbedError(f"disparity map is {disp.shape[1]}x{disp.shape[0]} but the images of {pair_path} "
                                f"are {pair.width}x{pair.height} (W x H)", disp_path)
        image = None
        if pair.left is not None and pair.left.exists():
            image = read_image(pair.left)
            if image.shape[:2] != disp.shape:
                raise RiverbedError(f"left image {pair.left} is not the size of the disparity map", disp_path)
        sources.append((disp, pair, image))
        confs.append(read_confidence(confidences[i], disp.shape) if confidences else None)
        if sparses:
            sparse = read_disparity(sparses[i])
            if sparse.shape != disp.shape:
                raise RiverbedError(f"sparse map is {sparse.shape[1]}x{sparse.shape[0]} but the disparity map is "
                                    f"{disp.shape[1]}x{disp.shape[0]} (W x H)", sparses[i])
            changes.append((disp, sparse, read_lidar_mask(masks[i], disp.shape), pair))
    return sources, confs, changes


def dsm_crs(sources, crs=None, clouds=()):
    """The CRS of a DSM of ``sources`` (and LiDAR ``clouds``): ``crs`` if given, else the pairs', else the first
    cloud's; RPC pairs take ``crs`` (default: the scene's UTM zone) and their points are converted to it.
    Returns ``(crs, rpc)``, ``rpc`` True for RPC pairs (heights ellipsoidal)."""
    rpc = [getattr(p, "kind", None) == "rpc" for _, p, _ in sources]
    if any(rpc):  # RPC pairs: points converted to crs (default: the scene's UTM zone), heights ellipsoidal
        if not all(rpc):
            raise RiverbedError("cannot merge RPC pair files with pinhole pair files in one DSM")
        crs = output_crs(sources[0][1], crs)
        for _, p, _ in sources:
            p.crs = crs
        return crs, True
    if crs is None:
        crs = next((p.crs for _, p, _ in sources if p.crs), None)
        if crs is None and clouds:
            found = resolve_crs(lidar_info(clouds[0]))
            crs = found.to_wkt() if found is not None else None
    return crs, False


def write_dsm_outputs(result, crs, output, *, points=None, changes=None, change_out=None, hillshade_png=None,
                      filled_band=False, nodata=float("nan"), creation=None, tags=None, overwrite=False):
    """Write a :class:`~riverbed_cli.products.dsm.DsmResult` and its products; they appear together or not at all.

    Parameters
    ----------
    result : DsmResult
        With ``points`` (``build_dsm(keep_points=True)``) when ``points`` is given.
    crs : str or None
        Written as is (assigned, not reprojected).
    output : path
        The DSM, a cloud-optimised GeoTIFF: band 1 the heights (``nodata`` where empty), band 2 with
        ``filled_band`` the cells hole filling filled (1).
    points : path, optional
        The image points: .las/.laz (RGB, CRS) or .ply.
    changes, change_out : list, path, optional
        The :func:`~riverbed_cli.products.change_map.change_map` of ``changes`` on the DSM's grid, written to
        ``change_out`` (m, match minus LiDAR; NaN elsewhere).
    hillshade_png : path, optional
        A hillshade picture of the DSM.
    creation, tags : optional
        GDAL creation options of the GeoTIFFs and the DSM's tags.

    Returns
    -------
    dict or None
        The change map's figures (:func:`~riverbed_cli.products.change_map.change_map`), None without one.
    """
    dsm = result.dsm
    if not np.isnan(nodata):
        dsm = np.where(np.isnan(dsm), np.float32(nodata), dsm)
    bands = [dsm] if not filled_band else [dsm, result.filled.astype(np.float32)]
    change_stats = None
    with output_group():  # the DSM, its points, its change map and its hillshade appear together or not at all
        write_geotiff(output, np.stack(bands), result.grid.transform, crs, nodata, creation, overwrite,
                      band_descriptions=["height", "filled"][: len(bands)], tags=tags or {})
        if points:
            xyz, rgb = result.points
            write_points(points, xyz, rgb, crs, overwrite=overwrite)
        if change_out:
            change, change_stats = change_map(changes, result.grid)
            write_geotiff(change_out, change, result.grid.transform, crs, float("nan"), creation, overwrite,
                          band_descriptions=["height change (m), match minus LiDAR"],
                          tags={"riverbed_change": "median height change of the LiDAR points the check dropped in "
                                                   "changed regions"})
        if hillshade_png:
            res = result.grid.resolution
            write_picture(hillshade_png, hillshade_picture(hillshade(result.dsm, res), result.dsm, res),
                          overwrite=overwrite)
    return change_stats
