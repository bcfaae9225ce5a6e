"""``riverbed rectify`` and ``riverbed orient``: how well rectified pairs share their rows, how exact the written
cameras are, the tie-point check, and pairs rectified from imported orientations.

    python benchmarks/bench_rectify.py [DATA] --write benchmarks/results_rectify.json --docs docs/rectify.md

Each figure is measured by the function of the test that holds it (imported from ``tests/``):

1. **rows**: the rows of matched features (``tests/test_rectify.py``: :func:`row_agreement`, SIFT, ratio test, RANSAC
   on F, Lucas-Kanade positions) of the sample block's raw frames 0 + 1 rectified, of the generator's own exactly
   rectified pair, of frames distorted and rectified with their distortion model, and of two wrong rectifications
   (the right frame's omega off by 0.005 deg; the distorted frames without their model).
2. **cameras**: LiDAR points through the pair and the remap maps against OpenCV's projectPoints (:func:`camera_check`,
   plain and distorted frames), SIFT features of the rectified and the raw left image against the predicted
   homography (:func:`content_agreement`), and ``riverbed match`` on a half-size rectification against the LiDAR
   (:func:`match_chain`).
3. **tie_points**: ``rectify``'s own check (ORB tie points) of the sample's raw frames and of the NGI frames
   (``aerial_ngi_orthority/ngi`` in ``DATA``), each with the right frame's rotation transposed, and the share of the
   reference's disparities (the LiDAR's, the DEM's) inside the range it writes (``tests/test_tie_points.py``).
4. **orient**: the NGI and ODM pairs rectified from ``riverbed orient``'s imports (``tests/test_orient.py``), and the
   ODM orientations against Orthority's conversion.

``--write`` stores the figures (the committed result file), ``--docs`` rewrites docs/rectify.md's four blocks from it
(``tests/test_rectify_doc.py`` checks them and the claims the text makes on the figures; the tests above hold each
measurement to its committed figure).
"""

import sys
import tempfile
from pathlib import Path

if __name__ == "__main__":  # the riverbed program's process settings (Numba's cache folder) before any kernel import
    from riverbed_cli.runtime import Env

    Env().__enter__()

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(ROOT / "tests"))
from datasets import rows_main  # noqa: E402
import test_orient as TO  # noqa: E402
import test_rectify as TR  # noqa: E402
import test_tie_points as TT  # noqa: E402

from riverbed_cli.geometry import rectify as RC  # noqa: E402

#: the row measurements, in the table's order: (key, label)
ROWS = [("rectified", "raw frames 0 + 1 rectified"),
        ("generator", "the generator's pair (rows exact by construction)"),
        ("distorted", "distorted frames, rectified with their model"),
        ("omega", f"right frame's ω off by {TR.OMEGA_OFF_DEG}°"),
        ("distorted_without_model", "distorted frames, rectified without their model")]
#: the tie-point checks, in the table's order: (key, pair, reference)
CHECKS = [("sample", "sample block, raw frames 0 + 1", "LiDAR"),
          ("sample_transposed", "the same, right rotation transposed", None),
          ("ngi", "NGI DMC frames 0184 + 0182", "DEM"),
          ("ngi_transposed", "the same, right rotation transposed", None)]
#: the import rows: (key, pair, orientations)
IMPORTS = [("ngi", "NGI DMC frames 0182 + 0184", "Orthority CSV"),
           ("ngi_transposed", "the same, right rotation transposed", "Orthority CSV, `Mᵀ` fed as `M`"),
           ("odm", "ODM images 0140 + 0142 (`--alpha -1 --size 1600x1200`)", "OpenSfM `reconstruction.json`")]


def _rounded(d, digits=4):
    """``d`` with its floats rounded to ``digits`` decimals (lists and nested dicts too)."""
    if isinstance(d, dict):
        return {k: _rounded(v, digits) for k, v in d.items()}
    if isinstance(d, list):
        return [_rounded(v, digits) for v in d]
    return round(d, digits) if isinstance(d, float) else d


def _significant(values, digits=3):
    """Floats to ``digits`` significant digits (the remap maps' errors, ~1e-5 px)."""
    return [float(f"{v:.{digits - 1}e}") for v in values]


def sample_figures(tmp):
    """The sample block's figures: rows, cameras, content, chain (tests/test_rectify.py)."""
    raw, lidar = TR.load_raw(), TR.load_lidar()
    imgs, (o0, o1) = raw
    rect = RC.rectify(imgs[0], o0, imgs[1], o1)
    dist = TR.distortion_case(raw, lidar)
    rows = {"rectified": TR.rows_of(rect, lidar), "generator": TR.generator_rows(lidar), "distorted": dist["rows"],
            "omega": TR.rows_of(RC.rectify(imgs[0], o0, imgs[1], TR.omega_off(o1)), lidar),
            "distorted_without_model": dist["rows_without_model"]}
    cameras = {}
    for name, check in (("plain", TR.camera_check(rect, (o0, o1), lidar)), ("distorted", dist["cameras"])):
        cameras[name] = {"worst_px": _significant(check["worst_px"]), "points": check["points"]}
    return {"rows": _rounded(rows), "cameras": cameras,
            "content": _rounded(TR.content_agreement(rect, imgs[0], o0)),
            "chain": _rounded(TR.match_chain(lidar, tmp / "half"))}


def run(data):
    with tempfile.TemporaryDirectory(prefix="bench_rectify_") as tmp:
        tmp = Path(tmp)
        for name in ("sample", "ngi_checks", "ngi_rows", "odm_rows"):
            (tmp / name).mkdir()
        out = sample_figures(tmp / "sample")
        out["tie_points"] = _rounded({**TT.sample_checks(tmp / "sample"), **TT.ngi_checks(data, tmp / "ngi_checks")})
        out["orient"] = _rounded({**TO.ngi_rows(data, tmp / "ngi_rows"), "odm": TO.odm_rows(data, tmp / "odm_rows"),
                                  "odm_vs_orthority": TO.odm_against_orthority(data)}, 5)
    return out


def _px(v, digits=3):
    return f"{v:.{digits}f}"


def rows_table(r):
    """The rows of matched features."""
    out = ["| pair | matches | median abs dy (px) | p95 abs dy (px) | mean dy (px) | largest regional median (px) "
           "| SIFT positions: median / p95 (px) |", "|---|---:|---:|---:|---:|---:|---:|"]
    for key, label in ROWS:
        s = r["rows"][key]
        out.append(f"| {label} | {s['n']} | {_px(s['median'])} | {_px(s['p95'])} | {s['mean']:+.3f} | "
                   f"{_px(s['regional_max'])} | {_px(s['sift_median'])} / {_px(s['sift_p95'])} |")
    return "\n".join(out)


def cameras_table(r):
    """The written cameras and the chain."""
    c, d, content, chain = r["cameras"]["plain"], r["cameras"]["distorted"], r["content"], r["chain"]
    return "\n".join([
        "| check | over | figure |", "|---|---|---:|",
        f"| LiDAR points through the written pair file and the remap maps, against OpenCV's `projectPoints`: "
        f"worst error | {min(c['points']):,} points per image or more | {max(c['worst_px']):.1e} px |",
        f"| the same, distorted frames | {min(d['points']):,} points per image or more | "
        f"{max(d['worst_px']):.1e} px |",
        f"| SIFT features of the rectified and the raw left image, against the homography the pair file and the "
        f"orientation predict: median error | {content['features']:,} features | {content['median_px']:.3f} px |",
        f"| `riverbed match` on a half-size rectification (`--size 600x400`), against the LiDAR's disparities "
        f"through the written pair file: median abs(d - d_lidar) | {chain['points']:,} points | "
        f"{chain['median_px']:.2f} px |",
        f"| the same: within 1 px | {chain['points']:,} points | {chain['within_1px']:.1f} % |"])


def tie_points_table(r):
    """``rectify``'s tie-point check."""
    out = ["| pair | tie points | median abs dy (px) | p90 abs dy (px) | mean dy (px) | range written (px) | "
           "reference's disparities (px) | inside the range | warning |", "|---|---:|---:|---:|---:|---|---|---:|---|"]
    for key, label, reference in CHECKS:
        c = r["tie_points"][key]
        if "dy_median_px" in c:
            dy = f"{c['dy_median_px']:.3f} | {c['dy_p90_px']:.3f} | {c['dy_mean_px']:+.3f}"
        else:
            dy = "– | – | –"
        rng = f"{c['disparity'][0]}–{c['disparity'][1]}" if "disparity" in c else "–"
        ref = (f"{c['reference'][0]:.1f}–{c['reference'][1]:.1f} ({reference}) | {c['reference_inside']:.2f} %"
               if reference else "– | –")
        out.append(f"| {label} | {c['tie_points']} | {dy} | {rng} | {ref} | {c['warning'] or 'none'} |")
    return "\n".join(out)


def orient_table(r):
    """Pairs rectified from imported orientations, and the ODM import against Orthority's."""
    o = r["orient"]
    out = ["| pair | orientations | SIFT matches | median abs dy (px) |", "|---|---|---:|---:|"]
    for key, label, source in IMPORTS:
        out.append(f"| {label} | {source} | {o[key]['matches']} | {o[key]['median_px']:.2f} |")
    v = o["odm_vs_orthority"]
    out += ["", "| ODM block, against Orthority's conversion | centres (m) | rotations (°) |", "|---|---:|---:|",
            f"| as Orthority converts (meridian convergence at the reference point: {v['convergence_deg']:.3f}°) | "
            f"{v['centres_m'][0]:.2f}–{v['centres_m'][1]:.2f} | "
            f"{v['rotations_deg'][0]:.4f}–{v['rotations_deg'][1]:.4f} |",
            f"| its offsets turned by the convergence and scaled, largest | {v['corrected_centres_m']:.4f} | "
            f"{v['corrected_rotations_deg']:.4f} |"]
    return "\n".join(out)


TABLES = [(rows_table, "<!-- bench_rectify rows: begin -->", "<!-- bench_rectify rows: end -->"),
          (cameras_table, "<!-- bench_rectify cameras: begin -->", "<!-- bench_rectify cameras: end -->"),
          (tie_points_table, "<!-- bench_rectify tie points: begin -->", "<!-- bench_rectify tie points: end -->"),
          (orient_table, "<!-- bench_rectify orient: begin -->", "<!-- bench_rectify orient: end -->")]


def main():
    rows_main(__doc__, run, TABLES)


if __name__ == "__main__":
    main()
