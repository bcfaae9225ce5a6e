"""Orientations from aero-triangulation exports (Orthority, OpenSfM / ODM, COLMAP) into riverbed's orientation files
(what ``riverbed orient`` runs; the formats' conventions are tabled in ``docs/rectify.md``, "Importing
orientations").

Each reader returns ``{image name: FrameOrientation}`` (:class:`~riverbed_cli.geometry.orientation.FrameOrientation`:
OpenCV camera matrix with pixel centres at integer coordinates, Brown distortion, world -> camera rotation,
projection centre, image size, CRS); :func:`orient_files` writes one orientation YAML per image. The Orthority
reader and the shared checks and geodesy live in :mod:`riverbed_cli.geometry.orientation_formats`.

- **Orthority**: interior YAML (camera id -> ``type``, ``im_size``, ``focal_len``, ``sensor_size``, ``cx``, ``cy``,
  ``k1``...) and exterior CSV (``filename, x, y, z, omega, phi, kappa``; or ``latitude, longitude, altitude``
  and/or ``roll, pitch, yaw``; degrees unless ``radians``; CRS from a ``.prj`` beside it) or GeoJSON (``xyz``,
  ``opk`` in radians, ``world_crs``). Orthority's ``R = Rx(omega) Ry(phi) Rz(kappa)`` rotates the camera (x right,
  y up, z back) into the world: the transpose of riverbed's ``M``, so the angles copy over unchanged.
- **OpenSfM / ODM** ``reconstruction.json``: axis-angle world -> camera rotations and translations
  (``X_cam = R X + t``, OpenCV axes) in a topocentric east-north-up frame at ``reference_lla``; centres and
  rotations are carried into the projected CRS (``crs``, or the UTM zone of the reference point) through pyproj
  (:func:`~riverbed_cli.geometry.orientation_formats.camera_to_grid`: grid convergence and scale included).
- **COLMAP** text model (``cameras.txt``, ``images.txt``): quaternion and translation world -> camera, OpenCV
  axes, pixel centres at half-integers (the principal point moves by -0.5 px); no CRS unless ``crs`` is given.
"""

import logging
import time
from pathlib import Path

import numpy as np

from ..errors import RiverbedError
from ..io.atomic import check_output_folder, output_group, releases_claims
from ..io.textfiles import load_text_data, read_text
from .orientation import orientation_dict, write_orientation
from .orientation_formats import (MAX_EXPORT_BYTES, PHOTO_TO_CV, camera_to_grid, distortion_coefficients, frame,
                                  geodetic_to_grid, image_size, interior, normalised_focal, number, numbers,
                                  projected_crs, read_orthority, rotation_from_axis_angle, rotation_from_quaternion,
                                  square_focal, topocentric_to_geodetic, transform_points, utm_crs)

log = logging.getLogger(__name__)

FORMATS = ("orthority", "opensfm", "colmap")
#: File name suffixes dropped from an image name to name its orientation file (``IMG_1.JPG`` -> ``IMG_1.yaml``).
IMAGE_SUFFIXES = (".tif", ".tiff", ".jpg", ".jpeg", ".png", ".jp2", ".bmp", ".webp", ".dng")

OPENSFM_COEFFS = {"perspective": ("k1", "k2"), "simple_radial": ("k1",), "radial": ("k1", "k2"),
                  "brown": ("k1", "k2", "k3", "p1", "p2")}
COLMAP_PARAMS = {"SIMPLE_PINHOLE": ("f", "cx", "cy"), "PINHOLE": ("fx", "fy", "cx", "cy"),
                 "SIMPLE_RADIAL": ("f", "cx", "cy", "k1"), "RADIAL": ("f", "cx", "cy", "k1", "k2"),
                 "OPENCV": ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2"),
                 "FULL_OPENCV": ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6")}
#: Largest deviation of a COLMAP quaternion's norm from 1 (it is normalised).
QUATERNION_TOL = 1e-3


# -- OpenSfM / ODM --------------------------------------------------------------------------------------------
def _opensfm_camera(params, key, path):
    if not isinstance(params, dict):
        raise RiverbedError(f"{key}: expected a mapping of camera parameters", path)
    model = params.get("projection_type")
    if model not in OPENSFM_COEFFS:
        raise RiverbedError(f"{key}.projection_type: camera model {model!r} is not supported (riverbed reads "
                            f"{', '.join(OPENSFM_COEFFS)}: OpenCV's Brown model, no fisheye or spherical)", path)
    width, height = image_size([params.get("width"), params.get("height")], f"{key}.width, height", path)
    side = max(width, height)
    hint = "OpenSfM's focal lengths are normalised, not in pixels or mm"
    if params.get("focal") is not None:
        fx = fy = normalised_focal(params["focal"], f"{key}.focal", path, hint)
    elif params.get("focal_x") is not None and params.get("focal_y") is not None:
        fx = normalised_focal(params["focal_x"], f"{key}.focal_x", path, hint)
        fy = normalised_focal(params["focal_y"], f"{key}.focal_y", path, hint)
    else:
        raise RiverbedError(f"{key}.focal: missing (focal, or focal_x and focal_y)", path)
    f = square_focal(fx * side, fy * side, f"{key}.focal_x, focal_y", path)
    cx = (width - 1) / 2 + side * number(params.get("c_x", 0.0), f"{key}.c_x", path)
    cy = (height - 1) / 2 + side * number(params.get("c_y", 0.0), f"{key}.c_y", path)
    coeffs = {k: number(params.get(k, 0.0), f"{key}.{k}", path) for k in OPENSFM_COEFFS[model]}
    return interior(f, cx, cy, distortion_coefficients(coeffs, key, path), width, height, f"{key}.focal", path)


def read_opensfm(path, *, crs=None):
    """``{image name: FrameOrientation}`` from an OpenSfM / ODM ``reconstruction.json``.

    Focal lengths and ``c_x``, ``c_y`` are normalised by the larger image side (``cx_px = (W - 1) / 2 +
    max(W, H) c_x``); shots hold ``X_cam = R X + t`` (``R`` from the axis-angle ``rotation``, OpenCV axes) in
    the topocentric east-north-up frame at ``reference_lla`` (WGS 84, ellipsoidal altitude). Centres and rotations
    are carried into ``crs`` (default: the UTM zone of the first reference point) through pyproj; heights stay
    ellipsoidal unless ``crs`` has a vertical datum.
    """
    data = load_text_data(path, "OpenSfM reconstruction", MAX_EXPORT_BYTES, fmt="json")[0]
    if not isinstance(data, list) or not data or not all(isinstance(r, dict) for r in data):
        raise RiverbedError("not an OpenSfM reconstruction (expected a list of reconstructions with cameras, "
                            "shots and reference_lla)", path)
    target = None if crs is None else projected_crs(crs, "--crs", None)
    frames = {}
    for i, rec in enumerate(data):
        where = f"[{i}]"
        for k in ("cameras", "shots", "reference_lla"):
            if not isinstance(rec.get(k), dict):
                extra = " (the reconstruction is not georeferenced)" if k == "reference_lla" else ""
                raise RiverbedError(f"{where}.{k}: missing{extra}", path)
        ref = rec["reference_lla"]
        lat, lon, alt = (number(ref.get(k), f"{where}.reference_lla.{k}", path)
                         for k in ("latitude", "longitude", "altitude"))
        if not (-90 <= lat <= 90 and -180 <= lon <= 360):
            raise RiverbedError(f"{where}.reference_lla: latitude {lat!r}, longitude {lon!r} out of range "
                                "(degrees expected)", path)
        target = target or utm_crs(lat, lon)
        to_lla, to_grid = topocentric_to_geodetic(lat, lon, alt), geodetic_to_grid(target)
        cameras = {}
        for name, shot in rec["shots"].items():
            key = f"{where}.shots.{name}"
            if not isinstance(shot, dict):
                raise RiverbedError(f"{key}: expected a mapping with rotation, translation, camera", path)
            for k in ("rotation", "translation", "camera"):
                if shot.get(k) is None:
                    raise RiverbedError(f"{key}.{k}: missing", path)
            cam_id = shot["camera"]
            if not isinstance(cam_id, str) or cam_id not in rec["cameras"]:
                raise RiverbedError(f"{key}.camera: {cam_id!r} is not in {where}.cameras", path)
            if cam_id not in cameras:
                cameras[cam_id] = _opensfm_camera(rec["cameras"][cam_id], f"{where}.cameras.{cam_id}", path)
            R = rotation_from_axis_angle(numbers(shot["rotation"], 3, f"{key}.rotation", path))
            t = np.array(numbers(shot["translation"], 3, f"{key}.translation", path))

            def enu_to_grid(points, key=key):
                lla = transform_points(to_lla, points, key, path)
                return transform_points(to_grid, lla, key, path)

            centre, R_grid = camera_to_grid(enu_to_grid, -R.T @ t, R, key, path)
            image = Path(name).name
            if image in frames:
                raise RiverbedError(f"{key}: image {image!r} given twice", path)
            frames[image] = frame(cameras[cam_id], PHOTO_TO_CV @ R_grid, centre, target, path)
    return frames


# -- COLMAP ---------------------------------------------------------------------------------------------------
def _lines(path, what):
    """``(line number, text)`` of a COLMAP text file, comment lines left out."""
    text = read_text(path, what, MAX_EXPORT_BYTES).lstrip("\ufeff")
    return [(n, line) for n, line in enumerate(text.splitlines(), 1) if not line.lstrip().startswith("#")]


def read_colmap_cameras(path):
    """``{camera id: Interior}`` of a COLMAP ``cameras.txt`` (principal point moved by -0.5 px: COLMAP puts pixel
    centres at half-integers, riverbed at integers)."""
    cameras = {}
    for n, line in _lines(path, "COLMAP cameras file"):
        tokens = line.split()
        if not tokens:
            continue
        if len(tokens) < 4:
            raise RiverbedError(f"line {n}: expected CAMERA_ID MODEL WIDTH HEIGHT PARAMS..., got {line.strip()!r}",
                                path)
        cam_id, model = tokens[0], tokens[1]
        if model not in COLMAP_PARAMS:
            raise RiverbedError(f"line {n}: camera model {model} is not supported (riverbed reads "
                                f"{', '.join(COLMAP_PARAMS)}: OpenCV's Brown model)", path)
        width, height = image_size([_parse_int(t) for t in tokens[2:4]], f"line {n}: WIDTH HEIGHT", path)
        names = COLMAP_PARAMS[model]
        if len(tokens) - 4 != len(names):
            raise RiverbedError(f"line {n}: {model} has {len(names)} parameters ({' '.join(names)}), got "
                                f"{len(tokens) - 4}", path)
        p = {name: number(t, f"line {n}: {name}", path) for name, t in zip(names, tokens[4:])}
        fx, fy = p.get("f", p.get("fx")), p.get("f", p.get("fy"))
        if not (fx > 0 and fy > 0):
            raise RiverbedError(f"line {n}: focal length must be positive, got {fx!r}, {fy!r}", path)
        f = square_focal(fx, fy, f"line {n}: fx, fy", path)
        dist = distortion_coefficients(p, f"line {n}: ", path)
        cameras[cam_id] = interior(f, p["cx"] - 0.5, p["cy"] - 0.5, dist, width, height, f"line {n}: focal length",
                                   path)
    return cameras


def _parse_int(text):
    """``text`` as an int, or ``text`` itself (refused by the caller's check)."""
    try:
        return int(text)
    except ValueError:
        return text


def _is_image_line(tokens):
    # POINTS2D lines are all numbers (X Y POINT3D_ID triples); an image line ends with a name
    return len(tokens) >= 10 and _number_or_none(tokens[9]) is None


def _number_or_none(text):
    try:
        return float(text)
    except ValueError:
        return None


def read_colmap(cameras_path, images_path, *, crs=None):
    """``{image name: FrameOrientation}`` from COLMAP's ``cameras.txt`` and ``images.txt``.

    ``images.txt`` holds ``QW QX QY QZ TX TY TZ``: ``X_cam = R(q) X + t`` (world -> camera, OpenCV axes). COLMAP's
    world has no CRS: ``crs`` (projected) is written when given, and the world is taken to be in it.
    """
    target = None if crs is None else projected_crs(crs, "--crs", None)
    cameras = read_colmap_cameras(cameras_path)
    lines = _lines(images_path, "COLMAP images file")
    frames = {}
    i = 0
    while i < len(lines):
        n, line = lines[i]
        tokens = line.split()
        i += 1
        if not tokens:
            continue
        if len(tokens) < 10:
            raise RiverbedError(f"line {n}: expected IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME, got "
                                f"{len(tokens)} fields", images_path)
        q = np.array([number(t, f"line {n}: {k}", images_path) for k, t in zip(("QW", "QX", "QY", "QZ"), tokens[1:5])])
        t = np.array([number(v, f"line {n}: {k}", images_path) for k, v in zip(("TX", "TY", "TZ"), tokens[5:8])])
        norm = float(np.linalg.norm(q))
        if abs(norm - 1.0) > QUATERNION_TOL:
            raise RiverbedError(f"line {n}: QW QX QY QZ: not a unit quaternion (norm {norm:.6g})", images_path)
        if tokens[8] not in cameras:
            raise RiverbedError(f"line {n}: camera {tokens[8]} is not in {Path(cameras_path).name}", images_path)
        name = Path(" ".join(tokens[9:])).name
        if name in frames:
            raise RiverbedError(f"line {n}: image {name!r} given twice", images_path)
        R = rotation_from_quaternion(*(q / norm))
        frames[name] = frame(cameras[tokens[8]], PHOTO_TO_CV @ R, -R.T @ t, target, images_path)
        if i < len(lines) and not _is_image_line(lines[i][1].split()):
            i += 1  # the image's POINTS2D line (blank when it has none)
    return frames


# -- inputs, selection, output --------------------------------------------------------------------------------
def _role(path):
    """What an input file is, from its name: ``(format, role)``."""
    name, suffix = path.name.lower(), path.suffix.lower()
    if name in ("cameras.txt", "images.txt"):
        return "colmap", name[:-4]
    if name == "points3d.txt":
        return "colmap", "points"
    if suffix in (".yaml", ".yml"):
        return "orthority", "interior"
    if suffix in (".csv", ".geojson", ".txt"):
        return "orthority", "exterior"
    if suffix == ".json":
        return ("opensfm", "reconstruction") if name.startswith("reconstruction") else ("orthority", "exterior")
    return None, None


def _expand(path):
    """The export files an input folder holds (COLMAP's cameras.txt and images.txt, or OpenSfM's
    reconstruction.json, also under ``opensfm/``); a file as it is."""
    if not path.is_dir():
        return [path]
    if (path / "cameras.txt").is_file() and (path / "images.txt").is_file():
        return [path / "cameras.txt", path / "images.txt"]
    for candidate in (path / "reconstruction.json", path / "opensfm" / "reconstruction.json"):
        if candidate.is_file():
            return [candidate]
    raise RiverbedError("folder holds neither COLMAP's cameras.txt and images.txt nor OpenSfM's "
                        "reconstruction.json", path)


def resolve_inputs(inputs, fmt="auto"):
    """The format and its files (``{role: Path}``) from the command's inputs.

    Orthority: an interior ``.yaml`` and an exterior ``.csv``/``.txt``/``.geojson``; OpenSfM: a
    ``reconstruction.json`` or a folder holding one; COLMAP: ``cameras.txt`` and ``images.txt`` or their folder.
    With ``fmt`` given, files whose names do not say their role are taken in that order (interior then exterior;
    cameras then images).
    """
    if fmt not in ("auto",) + FORMATS:
        raise RiverbedError(f"unknown format {fmt!r} (one of auto, {', '.join(FORMATS)})")
    paths = [p for given in inputs for p in _expand(Path(given))]
    if not paths:
        raise RiverbedError("no input files")
    for p in paths:
        if not p.is_file():
            raise RiverbedError("no such file", p)
    roles = [_role(p) for p in paths]
    if fmt == "auto":
        found = {f for f, _ in roles}
        if None in found or len(found) != 1:
            unknown = [p for p, (f, _) in zip(paths, roles) if f is None]
            if unknown:
                raise RiverbedError("cannot tell the export format from the file name; give --format", unknown[0])
            raise RiverbedError(f"inputs of several formats ({', '.join(sorted(found))}); give one export")
        fmt = found.pop()
    wanted = {"orthority": ("interior", "exterior"), "opensfm": ("reconstruction",),
              "colmap": ("cameras", "images")}[fmt]
    files = {}
    for p, (f, role) in zip(paths, roles):
        if f == fmt and role == "points":
            continue  # COLMAP's points3D.txt: not needed
        role = role if f == fmt and role in wanted and role not in files else None
        role = role or next((r for r in wanted if r not in files), None)
        if role is None:
            raise RiverbedError(f"one input too many for {fmt} (it takes {' and '.join(wanted)})", p)
        files[role] = p
    missing = [r for r in wanted if r not in files]
    if missing:
        raise RiverbedError(f"{fmt} needs {' and '.join(wanted)} files; missing: {', '.join(missing)}")
    return fmt, files


def import_orientations(inputs, fmt="auto", *, crs=None, radians=False, images=None):
    """``(format, files, {image name: FrameOrientation})`` from an export's files (:func:`resolve_inputs`),
    restricted to ``images`` (names, with or without their extension) when given."""
    fmt, files = resolve_inputs(inputs, fmt)
    if radians and fmt != "orthority":
        raise RiverbedError("--radians applies to Orthority's CSV files only")
    if fmt == "orthority":
        frames = read_orthority(files["interior"], files["exterior"], crs=crs, radians=radians)
    elif fmt == "opensfm":
        frames = read_opensfm(files["reconstruction"], crs=crs)
    else:
        frames = read_colmap(files["cameras"], files["images"], crs=crs)
    source = files.get("exterior") or files.get("reconstruction") or files.get("images")
    return fmt, files, select_frames(frames, images, source)


def image_stem(name):
    """An image name without its image-file suffix (``a.tif`` -> ``a``; ``a.b`` stays)."""
    path = Path(name)
    return path.stem if path.suffix.lower() in IMAGE_SUFFIXES else path.name


def select_frames(frames, images, source):
    """The frames named in ``images`` (an image's name or its :func:`image_stem`), in that order; all when None."""
    if not images:
        if not frames:
            raise RiverbedError("the export holds no images", source)
        return frames
    out = {}
    for wanted in images:
        hits = [k for k in frames if k == wanted] or [k for k in frames if image_stem(k) == image_stem(wanted)]
        if len(hits) != 1:
            listed = ", ".join(sorted(frames)[:8]) + (", ..." if len(frames) > 8 else "")
            problem = "is not in the export" if not hits else f"matches {len(hits)} images"
            raise RiverbedError(f"image {wanted!r} {problem} (it has {len(frames)}: {listed})", source)
        out[hits[0]] = frames[hits[0]]
    return out


def output_names(frames, source):
    """``{image name: orientation file name}`` (``STEM.yaml``); two images with one stem are refused."""
    names, seen = {}, {}
    for image in frames:
        out = image_stem(image) + ".yaml"
        if out in seen:
            raise RiverbedError(f"images {seen[out]!r} and {image!r} would both be written to {out}", source)
        seen[out] = image
        names[image] = out
    return names


def orientation_data(o):
    """The orientation file's contents for a :class:`FrameOrientation` (distortion left out when it is zero)."""
    dist = o.dist if np.any(o.dist != 0) else None
    return orientation_dict(o.K, o.R, o.centre, o.width, o.height, dist=dist, crs=o.crs)


@releases_claims
def orient_files(inputs, outdir, *, fmt="auto", crs=None, radians=False, images=None, overwrite=False):
    """Import an export's orientations and write ``OUTDIR/STEM.yaml`` for each image (what ``riverbed orient``
    runs).

    ``outdir`` is created if missing (its parent must exist). All files are claimed first, written under
    temporary names and renamed into place together once all are written; existing files are replaced only with
    ``overwrite``. Returns a summary dict.
    """
    t0 = time.perf_counter()
    fmt, files, frames = import_orientations(inputs, fmt, crs=crs, radians=radians, images=images)
    source = next(iter(files.values()))
    names = output_names(frames, source)
    outdir = Path(outdir)
    check_output_folder(outdir, names.values(), overwrite, inputs=list(files.values()))
    outdir.mkdir(exist_ok=True)
    listed = ", ".join(p.name for p in files.values())
    with output_group():
        for image, o in frames.items():
            write_orientation(outdir / names[image], orientation_data(o), overwrite=overwrite,
                              comment=f"Imported by riverbed orient from {fmt} ({listed}): image {image}.")
    summary = []
    for image, o in frames.items():
        summary.append({"image": image, "file": str(outdir / names[image]), "width": o.width, "height": o.height,
                        "focal_px": float(o.K[0, 0]), "principal_point_px": [float(o.K[0, 2]), float(o.K[1, 2])],
                        "centre": [float(v) for v in o.centre],
                        "omega_phi_kappa_deg": [float(a) for a in o.omega_phi_kappa]})
        log.info("%s: centre %s, omega phi kappa %s deg -> %s", image, ", ".join(f"{v:.3f}" for v in o.centre),
                 ", ".join(f"{a:.4f}" for a in o.omega_phi_kappa), names[image])
    crs_out = next(iter(frames.values())).crs
    return {"format": fmt, "inputs": {role: str(p) for role, p in files.items()}, "outdir": str(outdir),
            "crs": crs_out, "frames": summary, "seconds": round(time.perf_counter() - t0, 3)}
