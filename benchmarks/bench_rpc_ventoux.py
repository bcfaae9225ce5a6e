"""The real Pléiades Ventoux pair matched, through the commands as a user runs them (docs/rpc.md).

    python benchmarks/bench_rpc_ventoux.py [DATA] [--work DIR] [--spacing 4,8] [--json] [--no-picture]

DATA is the shared data folder (default ``$RIVERBED_DATA`` or ``../shared/data``). Each step is a subprocess
``riverbed ...`` (docs/rpc.md, "The real pair matched"):

1. ``riverbed rectify --rpc`` the two 500 x 500 crops with the SRTM tile (EGM96 -> ellipsoid through PROJ's grid; when
   the grid is missing, the documented fallback: ``--vertical ellipsoid``, SRTM read as ellipsoidal, ~51 m low);
2. a "LiDAR" made from the SRTM surface: points uniformly at random (seeded) over the left crop's ground footprint,
   one per ``s x s`` rectified pixels (ground sample distance 0.505 m) for each ``--spacing`` s, heights the SRTM's
   bilinear ellipsoidal heights (``read_dem``), written with laspy in UTM 31N with ellipsoidal heights
   (``EPSG:32631`` promoted to 3D: what ``cloud_to_wgs84`` takes in one pyproj step);
3. ``riverbed project`` (default z-buffer visibility and outlier removal) -> sparse disparities; ``riverbed match``
   guided (defaults: riverbed guide, tubes, confidence fusion) and unguided (``--guide none`` over the pair file's
   disparity range), ``--json`` seconds;
4. ``riverbed dsm`` of each (default UTM CRS and resolution, ``--hillshade``; the later DSMs on the first one's grid
   through ``--bounds``/``--resolution``), and of the LiDAR alone (``riverbed densify --method linear`` -> dsm);
   the SRTM (ellipsoidal, bilinear at each cell centre) is written on the DSM's grid, NaN outside the region both
   rectified images see of the left crop, and ``riverbed evaluate --dsm`` gives median, NMAD, RMSE of dz = DSM -
   SRTM and the completeness;
5. a markdown table; the guided DSM's hillshade (first spacing) is copied to ``docs/ventoux_dsm_hillshade.png``.

The SRTM is 90 m and the imagery 0.5 m: the SRTM-derived "LiDAR" is smooth, so the guided DSM sits near the SRTM by
construction. Unguided vs SRTM measures the matcher (against a coarse reference: real relief finer than 90 m, trees
and buildings, are "errors"); guided vs SRTM measures how hard the LiDAR pulls.
"""

import argparse
import json
import os
import subprocess
import sys
import tempfile
import textwrap
from pathlib import Path

import cv2
import laspy
import numpy as np
import rasterio
from pyproj import CRS, Transformer

from riverbed_cli.errors import RiverbedError
from riverbed_cli.geometry.pairfile import load_pairfile
from riverbed_cli.geometry.rpc_dem import geoid_to_ellipsoid_transformer, read_dem
from riverbed_cli.geometry.rpc_pair import footprint_bounds
from riverbed_cli.geometry.rpc_rectify import apply_h

VENTOUX = "satellite_pleiades_ventoux_shareloc/tests/data"
HGT = "dtm/srtm_ventoux/srtm90_non_void_filled/N44E005.hgt"
UTM = "EPSG:32631"
REPO = Path(__file__).resolve().parents[1]
PICTURE = REPO / "docs" / "ventoux_dsm_hillshade.png"
PICTURE_MAX_BYTES = 300 * 1024


def riverbed(*args, ok=(0,)):
    """Run ``riverbed ARGS`` (the script beside this Python, else on PATH) as a user would; its parsed ``--json``
    output, if any. An exit code outside ``ok`` raises with the command's stderr."""
    exe = Path(sys.executable).with_name("riverbed")
    cmd = [str(exe) if exe.exists() else "riverbed", *map(str, args)]
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode not in ok:
        raise RuntimeError(f"{' '.join(cmd)} failed ({r.returncode}): {r.stderr.strip()}")
    return json.loads(r.stdout) if "--json" in cmd else None


def rectify(data, work):
    """Step 1: ``riverbed rectify --rpc`` the Ventoux crops into ``work/rect``; (its JSON, the vertical datum used)."""
    base = Path(data) / VENTOUX / "rectification"
    hgt = Path(data) / VENTOUX / HGT
    try:
        geoid_to_ellipsoid_transformer("EPSG:5773")
        vertical = []
    except RiverbedError:    # no EGM96 grid (Debian's proj-data): docs/rpc.md's fallback, SRTM read as ellipsoidal
        vertical = ["--vertical", "ellipsoid"]
    s = riverbed("rectify", "--rpc", base / "left_image.tif", base / "left_image.geom", base / "right_image.tif",
                 base / "right_image.geom", "-o", work / "rect", "--dem", hgt, *vertical, "--json")
    return s, ("ellipsoid (fallback: no EGM96 grid)" if vertical else "EGM96 -> ellipsoid (PROJ grid)")


def srtm_dem(data, pair, vertical):
    """The SRTM tile over the left crop's footprint as ellipsoidal heights (``read_dem``)."""
    bounds = footprint_bounds(pair.rpc_left, pair.roi, pair.rpc_left.height_off)
    return read_dem(Path(data) / VENTOUX / HGT, bounds=bounds, margin_deg=0.01,
                    vertical="ellipsoid" if vertical.startswith("ellipsoid") else None)


def seen_mask(pair, right_size, lon, lat, h):
    """True where the ground point is inside both input crops (the left ROI and the right image's pixels): the
    region both images see, where matching can measure anything."""
    xl, yl, xr, yr = pair.project(lon, lat, h)
    c, r = apply_h(np.linalg.inv(pair.rectification.H_left), xl, yl)
    cr, rr = apply_h(np.linalg.inv(pair.rectification.H_right), xr, yr)
    x0, y0, w, hh = pair.roi
    wr, hr = right_size
    return (np.isfinite(h) & (c >= x0) & (c <= x0 + w - 1) & (r >= y0) & (r <= y0 + hh - 1) & (cr >= 0)
            & (cr <= wr - 1) & (rr >= 0) & (rr <= hr - 1))


def write_srtm_lidar(path, pair, dem, gsd, spacing_px, seed=0):
    """Step 2: an SRTM-surface "LiDAR" LAS, one point per ``spacing_px`` x ``spacing_px`` rectified pixels.

    Points uniformly at random over the UTM bounding box of the left crop's footprint (as an airborne survey
    covers the whole scene: ``riverbed project`` keeps what lands in both rectified images); heights bilinear on the
    SRTM (ellipsoidal, m); written with laspy (LAS 1.4 point format 6, WKT CRS, 1 mm steps,
    class 2 ground) in UTM 31N + ellipsoidal heights. Returns the number of points written.
    """
    to_utm = Transformer.from_crs("EPSG:4326", UTM, always_xy=True)
    lon0, lat0, lon1, lat1 = footprint_bounds(pair.rpc_left, pair.roi, dem.mean_height)
    e, n = to_utm.transform(np.array([lon0, lon1, lon0, lon1]), np.array([lat0, lat0, lat1, lat1]))
    area = (e.max() - e.min()) * (n.max() - n.min())
    count = int(round(area / (spacing_px * gsd) ** 2))
    rng = np.random.default_rng(seed)
    ee = rng.uniform(e.min(), e.max(), count)
    nn = rng.uniform(n.min(), n.max(), count)
    lon, lat = to_utm.transform(ee, nn, direction="INVERSE")
    h = dem.height(lon, lat)
    ok = np.isfinite(h)
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.scales = np.array([0.001, 0.001, 0.001])
    header.offsets = np.floor([ee.min(), nn.min(), 0.0])
    header.add_crs(CRS(UTM).to_3d())
    las = laspy.LasData(header)
    las.x, las.y, las.z = ee[ok], nn[ok], h[ok]
    las.classification = np.full(int(ok.sum()), 2, np.uint8)
    las.write(str(path))
    return int(ok.sum())


def srtm_on_grid(dsm_path, ref_path, pair, right_size, dem):
    """Step 4's reference: the SRTM (ellipsoidal) at the centre of every cell of the DSM's grid, NaN where the
    cell's ground is outside one of the two input crops (:func:`seen_mask`); written as a GeoTIFF."""
    with rasterio.open(dsm_path) as ds:
        profile = ds.profile.copy()
        t, shape, crs = ds.transform, (ds.height, ds.width), ds.crs
    rows, cols = np.mgrid[0:shape[0], 0:shape[1]]
    x, y = t * (cols + 0.5, rows + 0.5)
    lon, lat = Transformer.from_crs(crs, "EPSG:4326", always_xy=True).transform(x, y)
    h = dem.height(lon, lat)
    ref = np.where(seen_mask(pair, right_size, lon, lat, h), h, np.nan).astype(np.float32)
    profile.update(driver="GTiff", count=1, dtype="float32", nodata=np.nan, compress="deflate")
    for key in ("blockxsize", "blockysize", "tiled", "interleave"):
        profile.pop(key, None)
    with rasterio.open(ref_path, "w", **profile) as out:
        out.write(ref, 1)
    return ref


def nmad_after_plane(dsm_path, ref):
    """NMAD (m) of dz = DSM - reference once the best plane in (x, y) is removed: the part of the difference finer
    than a tilt (a 250 m crop spans ~3 SRTM posts, so a tilt is what the SRTM can get wrong the most)."""
    with rasterio.open(dsm_path) as ds:
        dz = ds.read(1).astype(np.float64) - ref
    y, x = np.nonzero(np.isfinite(dz))
    z = dz[y, x]
    a = np.stack([x, y, np.ones_like(x)], axis=1).astype(np.float64)
    res = z - a @ np.linalg.lstsq(a, z, rcond=None)[0]
    return float(1.4826 * np.median(np.abs(res - np.median(res))))


def dsm_grid(path):
    with rasterio.open(path) as ds:
        return (ds.bounds.left, ds.bounds.bottom, ds.bounds.right, ds.bounds.top), ds.res[0]


def run(data, work, spacings=(4, 8), picture=None, baseline=True):
    """Steps 1-5; returns the summary (dict) with one row per (spacing, method); ``baseline``: also the LiDAR-only
    DSMs (``riverbed densify --method linear``)."""
    work = Path(work)
    work.mkdir(parents=True, exist_ok=True)
    rect, vertical = rectify(data, work)
    pair_file = work / "rect" / "pair.yaml"
    pair = load_pairfile(pair_file, accept_rpc=True)
    dem = srtm_dem(data, pair, vertical)
    with rasterio.open(Path(data) / VENTOUX / "rectification" / "right_image.tif") as ds:
        right_size = ds.width, ds.height
    left, right = work / "rect" / "left.tif", work / "rect" / "right.tif"
    dmin, dmax = int(np.floor(pair.disparity[0])), int(np.ceil(pair.disparity[1]))
    summary = {"vertical": vertical, "rectify": {k: rect[k] for k in ("width", "height", "heights", "disparity",
                                                                      "pointing_row_offset_px", "seconds")},
               "rows": []}
    # unguided once: it does not depend on the LiDAR
    unguided = work / "unguided.tif"
    m_un = riverbed("match", left, right, "--guide", "none", "--min-disp", dmin, "--max-disp", dmax, "-o", unguided,
                    "--json")
    grid, ref = None, None
    gsd = None
    for spacing in spacings:
        tag = f"s{spacing}"
        cloud = work / f"srtm_lidar_{tag}.las"
        sparse = work / f"sparse_{tag}.tif"
        guided = work / f"guided_{tag}.tif"
        dense = work / f"lidar_linear_{tag}.tif"
        if gsd is None:    # the default DSM resolution: the left image's GSD at the scene's centre
            from riverbed_cli.geometry.rpc_geometry import ground_sample_distance
            gsd = float(ground_sample_distance(pair))
        n_pts = write_srtm_lidar(cloud, pair, dem, gsd, spacing, seed=spacing)
        p = riverbed("project", cloud, pair_file, "-o", sparse, "--json")
        # the SRTM guides as it is (--lidar-check off): the figures measure the geometry against that same SRTM
        m_g = riverbed("match", left, right, "--sparse", sparse, "--lidar-check", "off", "-o", guided, "--json")
        runs = [("guided", guided, m_g["seconds"])]
        if baseline:
            riverbed("densify", sparse, "-o", dense, "--method", "linear")
            runs.append(("lidar linear", dense, None))
        if spacing == spacings[0]:
            runs.insert(0, ("unguided", unguided, m_un["seconds"]))
        for name, disp, seconds in runs:
            out = work / f"dsm_{name.replace(' ', '_')}_{tag}.tif"
            shade = out.with_suffix(".png")
            extra = [] if grid is None else ["--bounds", *grid[0], "--resolution", grid[1]]
            riverbed("dsm", disp, pair_file, "-o", out, "--hillshade", shade, *extra, "--json")
            if grid is None:
                grid = dsm_grid(out)
                ref_path = work / "srtm_on_dsm_grid.tif"
                ref = srtm_on_grid(out, ref_path, pair, right_size, dem)
            ev = riverbed("evaluate", "--dsm", out, ref_path, "--json")
            summary["rows"].append({"spacing_px": spacing, "lidar_points": n_pts, "kept": p["kept"],
                                    "method": name, "match_seconds": seconds, "median": ev["median"],
                                    "nmad": ev["nmad"], "nmad_plane": nmad_after_plane(out, ref), "rmse": ev["rmse"],
                                    "completeness": ev["completeness"], "n": ev["n"], "hillshade": str(shade)})
            if picture is not None and name == "guided" and spacing == spacings[0]:
                copy_picture(shade, picture)
    summary["reference_cells"] = int(np.isfinite(ref).sum())
    summary["grid"] = {"bounds": list(grid[0]), "resolution": grid[1]}
    return summary


def copy_picture(src, dst):
    """The hillshade PNG into docs/, re-encoded (and halved until it is under 300 KiB)."""
    img = cv2.imread(str(src), cv2.IMREAD_UNCHANGED)
    while True:
        ok, buf = cv2.imencode(".png", img, [cv2.IMWRITE_PNG_COMPRESSION, 9])
        if len(buf) < PICTURE_MAX_BYTES:
            break
        img = cv2.resize(img, (img.shape[1] // 2, img.shape[0] // 2), interpolation=cv2.INTER_AREA)
    Path(dst).write_bytes(buf.tobytes())


def table(summary):
    lines = ["| LiDAR spacing (rectified px) | points (kept) | method | median dz (m) | NMAD (m) | "
             "NMAD, plane removed (m) | RMSE (m) | completeness (%) |",
             "|---|---|---|---|---|---|---|---|"]
    for r in summary["rows"]:
        pts = "—" if r["method"] == "unguided" else f"{r['lidar_points']} ({r['kept']})"
        sp = "—" if r["method"] == "unguided" else f"{r['spacing_px']} x {r['spacing_px']}"
        lines.append(f"| {sp} | {pts} | {r['method']} | {r['median']:.2f} | {r['nmad']:.2f} | "
                     f"{r['nmad_plane']:.2f} | {r['rmse']:.2f} | {r['completeness']:.1f} |")
    return "\n".join(lines)


#: the markers of docs/rpc.md's block of this benchmark
BEGIN, END = "<!-- bench_rpc_ventoux begin -->", "<!-- bench_rpc_ventoux end -->"


def doc_text(summary):
    """docs/rpc.md's block: the LiDAR and reference figures, the table, and what the unguided row says."""
    rows = {(r["spacing_px"], r["method"]): r for r in summary["rows"]}
    first = summary["rows"][0]["spacing_px"]
    lidar = sorted({(r["spacing_px"], r["lidar_points"], r["kept"]) for r in summary["rows"]})
    u, g = rows[first, "unguided"], rows[first, "guided"]
    r, grid = summary["rectify"], summary["grid"]
    text = [f"Rectified {r['width']} x {r['height']}, heights {r['heights'][0]:.1f}–{r['heights'][1]:.1f} m, d in "
            f"{r['disparity'][0]:.0f}–{r['disparity'][1]:.1f} px ({summary['vertical']}). The \"LiDAR\": "
            + ", ".join(f"{n} points at one per {s} x {s} px ({k} kept by `riverbed project`)" for s, n, k in lidar)
            + f". The reference: {summary['reference_cells']} cells of the DSM grid ({grid['resolution']} m).",
            "", table(summary), "",
            f"The unguided row against the coarse reference: median {u['median']:+.2f} m, NMAD {u['nmad']:.1f} m, "
            f"{u['nmad_plane']:.1f} m with the best plane removed; the guided row sits on the SRTM (median "
            f"{g['median']:+.2f} m, NMAD {g['nmad']:.2f} m at {first} x {first} px)."]
    return "\n".join(textwrap.fill(t, 116, break_on_hyphens=False) if not t.startswith("|") else t for t in text)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("data", nargs="?", default=os.environ.get("RIVERBED_DATA", str(REPO.parent / "shared" / "data")))
    ap.add_argument("--work", help="work folder (default: a temporary one, removed)")
    ap.add_argument("--spacing", default="4,8", help="LiDAR spacings in rectified pixels, comma-separated")
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--no-picture", action="store_true", help=f"do not write {PICTURE.relative_to(REPO)}")
    ap.add_argument("--write", help="store the summary in this JSON file (benchmarks/results_rpc_ventoux.json)")
    ap.add_argument("--rows", help="take the summary from this JSON file instead of running")
    ap.add_argument("--docs", help="rewrite this Markdown file's block (docs/rpc.md)")
    a = ap.parse_args(argv)
    spacings = tuple(int(s) for s in a.spacing.split(","))
    picture = None if a.no_picture else PICTURE
    if a.rows:
        summary = json.loads(Path(a.rows).read_text())
    elif a.work:
        summary = run(a.data, a.work, spacings, picture)
    else:
        with tempfile.TemporaryDirectory() as tmp:
            summary = run(a.data, tmp, spacings, picture)
    if a.write:  # without the temporary hillshades' paths
        rows = [{k: v for k, v in r.items() if k != "hillshade"} for r in summary["rows"]]
        Path(a.write).write_text(json.dumps({**summary, "rows": rows}, indent=1) + "\n")
    if a.docs:
        sys.path.insert(0, str(Path(__file__).resolve().parent))
        from datasets import rewrite_block

        rewrite_block(a.docs, BEGIN, END, doc_text(summary))
    if a.json:
        print(json.dumps(summary, indent=1))
    else:
        print(f"heights: {summary['vertical']}; rectified {summary['rectify']['width']} x "
              f"{summary['rectify']['height']}, d {summary['rectify']['disparity']}; SRTM reference cells "
              f"{summary['reference_cells']} at {summary['grid']['resolution']} m")
        print(table(summary))
    return 0


if __name__ == "__main__":
    sys.exit(main())
