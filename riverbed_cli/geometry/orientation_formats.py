"""What the orientation importers (:mod:`riverbed_cli.geometry.orientation_import`) share: checked numbers, one
frame's camera from its parts, the geodesy that carries positions and rotations into a projected CRS; and the
reader of Orthority's files (interior YAML, exterior CSV or GeoJSON).

Rotations cross from one frame of axes to another (OpenSfM's topocentric east-north-up, the local north-east-down
of roll/pitch/yaw) the same way: the camera centre and points one metre ahead and behind it along each camera axis
are transformed through pyproj, each axis is rebuilt from its two points (central differences) and the three are
orthonormalised (SVD). That takes the grid convergence, the direction of the local vertical at the camera and the
map's scale factor into account; what remains is riverbed's approximation that the projected CRS is Cartesian
(easting, northing, height) around the frames.
"""

import csv
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from pyproj import CRS, Transformer
from pyproj.exceptions import CRSError, ProjError

from ..errors import RiverbedError
from ..io.textfiles import load_text_data, read_text
from .orientation import FrameOrientation, opk_to_matrix, scalar

#: Photogrammetric image axes (x right, y up, z back) <-> OpenCV camera axes (x right, y down, z forward).
PHOTO_TO_CV = np.diag([1.0, -1.0, -1.0])
#: Largest relative difference of fx and fy still read as square pixels (their mean is used).
SQUARE_PIXEL_RTOL = 1e-6
#: Focal lengths in pixels outside this share of the larger image side are refused as a unit mistake
#: (field of view wider than 168 deg or narrower than 0.3 deg).
FOCAL_SHARE = (0.05, 200.0)
#: Largest normalised focal length (focal length / larger sensor side) accepted: a field of view under 5.7 deg is
#: far more likely a focal length in mm given without its sensor size.
NORMALISED_FOCAL_MAX = 10.0
#: Half the distance between the two points that rebuild a camera axis in another CRS (metres).
AXIS_STEP = 1.0
#: Distortion coefficients some formats have and riverbed's model lacks: accepted when zero.
UNMODELLED = ("k4", "k5", "k6", "s1", "s2", "s3", "s4", "tx", "ty")
ORTHORITY_COEFFS = {"pinhole": (), "brown": ("k1", "k2", "p1", "p2", "k3"),
                    "opencv": ("k1", "k2", "p1", "p2", "k3") + UNMODELLED}
ORTHORITY_KEYS = ("type", "im_size", "focal_len", "sensor_size", "cx", "cy", "name")
#: Orthority's CSV field order when the file has no header (the legacy simple-ortho format).
LEGACY_FIELDS = ("filename", "x", "y", "z", "omega", "phi", "kappa")
#: Largest export read (an OpenSfM reconstruction or a COLMAP images.txt carries its tie points).
MAX_EXPORT_BYTES = 2**30
#: Largest Orthority interior file or ``.prj`` read.
MAX_SMALL_BYTES = 1_000_000
#: Geographic CRS of latitude, longitude and (ellipsoidal) altitude, as Orthority and OpenSfM take them.
LLA_CRS = "EPSG:4979"


@dataclass(frozen=True)
class Interior:
    """One camera's interior orientation in riverbed's terms.

    Attributes
    ----------
    focal_px : float
        Focal length in pixels (square pixels).
    cx, cy : float
        Principal point in pixels, pixel centres at integer coordinates.
    dist : tuple of float
        ``k1, k2, p1, p2, k3`` (OpenCV's order and Brown model on normalised coordinates).
    width, height : int
        Image size in pixels.
    """

    focal_px: float
    cx: float
    cy: float
    dist: tuple
    width: int
    height: int


def number(value, key, path, *, positive=False):
    """``value`` as a finite float (not a YAML/JSON boolean), or a :class:`RiverbedError` naming ``key`` in
    ``path`` (:func:`~riverbed_cli.geometry.orientation.scalar`)."""
    if isinstance(value, bool):
        raise RiverbedError(f"{key}: expected a number, got {value!r}", path)
    return scalar(value, key, path, positive)


def numbers(value, n, key, path, *, positive=False):
    """``value`` as a list of ``n`` finite floats."""
    if not isinstance(value, (list, tuple)) or len(value) != n:
        got = f"{len(value)} values" if isinstance(value, (list, tuple)) else repr(value)
        raise RiverbedError(f"{key}: expected {n} numbers, got {got}", path)
    return [number(v, key, path, positive=positive) for v in value]


def image_size(value, key, path):
    """``[width, height]`` as two positive integers."""
    if (not isinstance(value, (list, tuple)) or len(value) != 2
            or not all(isinstance(v, int) and not isinstance(v, bool) and 0 < v <= 10_000_000 for v in value)):
        raise RiverbedError(f"{key}: expected [width, height] in pixels (two positive integers), got {value!r}",
                            path)
    return int(value[0]), int(value[1])


def normalised_focal(value, key, path, hint):
    """A focal length normalised by the larger image side, refused above :data:`NORMALISED_FOCAL_MAX`."""
    f = number(value, key, path, positive=True)
    if f > NORMALISED_FOCAL_MAX:
        raise RiverbedError(f"{key}: {value!r} is read as normalised by the larger image side (a field of view of "
                            f"{math.degrees(2 * math.atan(0.5 / f)):.2g} deg): {hint}", path)
    return f


def square_focal(fx, fy, key, path):
    """One focal length from ``fx`` and ``fy`` (pixels): riverbed's orientation files hold square pixels."""
    if abs(fx - fy) > SQUARE_PIXEL_RTOL * max(abs(fx), abs(fy)):
        raise RiverbedError(f"{key}: non-square pixels (fx {fx:.9g} px, fy {fy:.9g} px); riverbed's orientation "
                            "files hold one focal length", path)
    return fx if fx == fy else (fx + fy) / 2


def interior(focal_px, cx, cy, dist, width, height, key, path):
    """An :class:`Interior`, its focal length checked for a plausible field of view (a unit mistake, such as a
    focal length in mm read as normalised, gives a field of view of a few hundredths of a degree)."""
    share = focal_px / max(width, height)
    if not FOCAL_SHARE[0] <= share <= FOCAL_SHARE[1]:
        fov = math.degrees(2 * math.atan(0.5 / share)) if share > 0 else 180.0
        raise RiverbedError(f"{key}: a focal length of {focal_px:.6g} px for a {width}x{height} image (field of "
                            f"view {fov:.3g} deg) is implausible: wrong units?", path)
    return Interior(float(focal_px), float(cx), float(cy), tuple(float(v) for v in dist), int(width), int(height))


def distortion_coefficients(values, key, path):
    """``(k1, k2, p1, p2, k3)`` from a mapping of coefficients (missing ones 0); unmodelled ones must be 0."""
    for name in UNMODELLED:
        if values.get(name, 0.0) != 0.0:
            raise RiverbedError(f"{key}{name}: {values[name]!r} is not zero; riverbed's distortion model has k1, "
                                "k2, k3, p1, p2 only", path)
    return tuple(values.get(name, 0.0) for name in ("k1", "k2", "p1", "p2", "k3"))


def frame(inner, M, centre, crs, path):
    """A :class:`FrameOrientation` from an :class:`Interior`, the photogrammetric rotation ``M`` (object -> image,
    y up, z back) and the projection centre."""
    K = np.array([[inner.focal_px, 0.0, inner.cx], [0.0, inner.focal_px, inner.cy], [0.0, 0.0, 1.0]])
    return FrameOrientation(K=K, dist=np.array(inner.dist, np.float64), R=PHOTO_TO_CV @ np.asarray(M, np.float64),
                            centre=np.asarray(centre, np.float64), width=inner.width, height=inner.height, crs=crs,
                            path=path)


def rotation_from_axis_angle(vector):
    """The rotation matrix of an axis-angle vector (Rodrigues; angle = its length, radians)."""
    v = np.asarray(vector, np.float64)
    angle = float(np.linalg.norm(v))
    if angle == 0.0:
        return np.eye(3)
    k = v / angle
    Kx = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + math.sin(angle) * Kx + (1.0 - math.cos(angle)) * (Kx @ Kx)


def rotation_from_quaternion(qw, qx, qy, qz):
    """The rotation matrix of a unit quaternion (Hamilton convention, scalar first, as COLMAP writes it)."""
    w, x, y, z = qw, qx, qy, qz
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


# -- CRSs and transformations ---------------------------------------------------------------------------------
def projected_crs(text, what, path):
    """``text`` (anything pyproj reads: EPSG:32651, WKT, PROJ string) checked to be a projected CRS; returns the
    text, stripped, to be written as the orientation file's ``crs``."""
    text = str(text).strip()
    try:
        crs = CRS.from_user_input(text)
    except CRSError:
        raise RiverbedError(f"{what}: unknown CRS {_short(text)!r}", path) from None
    if not crs.is_projected:
        raise RiverbedError(f"{what}: {_short(text)} is not a projected CRS (riverbed's centres are easting, "
                            "northing, height in metres)", path)
    return text


def _short(text, limit=60):
    text = " ".join(text.split())
    return text if len(text) <= limit else text[:limit - 3] + "..."


def utm_crs(lat, lon):
    """The WGS 84 UTM zone CRS of a point, as ``EPSG:326NN`` (north) or ``EPSG:327NN`` (south)."""
    zone = int(math.floor((lon + 180.0) / 6.0)) % 60 + 1
    return f"EPSG:{(32600 if lat >= 0 else 32700) + zone}"


def transform_points(transformer, xyz, what, path):
    """``(N, 3)`` points through a pyproj ``Transformer`` (x, y, z order); a :class:`RiverbedError` when PROJ cannot
    (a missing grid, a point outside the CRS's area)."""
    xyz = np.asarray(xyz, np.float64).reshape(-1, 3)
    try:
        out = np.stack(transformer.transform(xyz[:, 0], xyz[:, 1], xyz[:, 2], errcheck=True), axis=1)
    except ProjError as e:
        raise RiverbedError(f"cannot transform {what}: {str(e).splitlines()[0]}", path) from None
    if not np.isfinite(out).all():
        raise RiverbedError(f"cannot transform {what} (PROJ gave no finite result)", path)
    return out


def geodetic_to_grid(crs, lla_crs=LLA_CRS):
    """Transformer from longitude, latitude (degrees), height to the projected ``crs`` (easting, northing, height;
    a 2D CRS keeps the height as it is)."""
    return Transformer.from_crs(CRS.from_user_input(lla_crs), CRS.from_user_input(crs), always_xy=True)


def topocentric_to_geodetic(lat, lon, alt):
    """Transformer from a topocentric east-north-up frame (metres, WGS 84, origin at ``lat, lon, alt``) to
    longitude, latitude (degrees) and ellipsoidal height: OpenSfM's reference frame."""
    pipeline = (f"+proj=pipeline +step +inv +proj=topocentric +ellps=WGS84 +lat_0={lat!r} +lon_0={lon!r} "
                f"+h_0={alt!r} +step +inv +proj=cart +ellps=WGS84 +step +proj=unitconvert +xy_in=rad +xy_out=deg")
    return Transformer.from_pipeline(pipeline)


def camera_to_grid(to_grid, centre, R_cv, what, path):
    """Centre and OpenCV rotation of a camera given in a local Cartesian frame, in the projected CRS.

    Parameters
    ----------
    to_grid : callable
        ``(N, 3)`` local points -> ``(N, 3)`` projected points.
    centre : (3,) float
        Projection centre, local frame.
    R_cv : (3, 3) float
        Local frame -> OpenCV camera axes (its rows are the camera axes in the local frame).

    Returns
    -------
    centre : (3,) float64
    R_cv : (3, 3) float64
        Projected CRS -> OpenCV camera axes: each axis through :data:`AXIS_STEP` m central differences, the
        nearest rotation (SVD) taking out the map's scale factor.
    """
    centre = np.asarray(centre, np.float64)
    R_cv = np.asarray(R_cv, np.float64)
    points = [centre]
    for axis in R_cv:
        points += [centre + AXIS_STEP * axis, centre - AXIS_STEP * axis]
    grid = to_grid(np.stack(points))
    axes = np.stack([(grid[1 + 2 * i] - grid[2 + 2 * i]) / (2 * AXIS_STEP) for i in range(3)])
    u, _, vt = np.linalg.svd(axes)
    rotation = u @ vt
    if np.linalg.det(rotation) < 0:
        raise RiverbedError(f"{what}: the CRS's axes are not east, north, up (a left-handed frame)", path)
    return grid[0], rotation


def rpy_to_matrix(roll, pitch, yaw):
    """Camera (photogrammetric axes) -> local north-east-down rotation of roll, pitch, yaw (degrees), for the usual
    drone mount (Pix4D's convention, as Orthority reads it): body x forward, y right, z down; camera x = body y,
    camera y = body x, camera z = -body z; ``C_nb = Rz(yaw) Ry(pitch) Rx(roll)``."""
    r, p, y = (math.radians(a) for a in (roll, pitch, yaw))
    Rx = np.array([[1.0, 0.0, 0.0], [0.0, math.cos(r), -math.sin(r)], [0.0, math.sin(r), math.cos(r)]])
    Ry = np.array([[math.cos(p), 0.0, math.sin(p)], [0.0, 1.0, 0.0], [-math.sin(p), 0.0, math.cos(p)]])
    Rz = np.array([[math.cos(y), -math.sin(y), 0.0], [math.sin(y), math.cos(y), 0.0], [0.0, 0.0, 1.0]])
    body_from_camera = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
    return Rz @ Ry @ Rx @ body_from_camera


#: Local north-east-down -> east-north-up axes.
NED_TO_ENU = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])


def rpy_camera_to_grid(lat, lon, alt, roll, pitch, yaw, crs, lla_crs, what, path):
    """Photogrammetric ``M`` (grid -> image axes) of a camera at ``lat, lon, alt`` with roll, pitch, yaw (degrees)
    relative to the local north-east-down frame there, in the projected ``crs``."""
    enu_from_camera = NED_TO_ENU @ rpy_to_matrix(roll, pitch, yaw)
    R_cv_enu = PHOTO_TO_CV @ enu_from_camera.T
    to_lla = topocentric_to_geodetic(lat, lon, alt)
    to_grid = geodetic_to_grid(crs, lla_crs)

    def enu_to_grid(points):
        return transform_points(to_grid, transform_points(to_lla, points, what, path), what, path)

    _, R_cv = camera_to_grid(enu_to_grid, np.zeros(3), R_cv_enu, what, path)
    return PHOTO_TO_CV @ R_cv


# -- Orthority ------------------------------------------------------------------------------------------------
def read_orthority_interior(path):
    """Cameras of an Orthority interior parameter file: ``{camera id: Interior}``.

    ``focal_len`` is in the units of ``sensor_size``, or without it normalised by the larger image side;
    ``cx``, ``cy`` are offsets of the principal point from the image centre normalised by the larger image side
    (Orthority's and OpenSfM's normalised image coordinates): ``cx_px = (W - 1) / 2 + max(W, H) cx``.
    """
    data = load_text_data(path, "Orthority interior parameter file", MAX_SMALL_BYTES, fmt="yaml")[0]
    if isinstance(data, dict) and isinstance(data.get("camera"), dict) and "type" in data["camera"]:
        data = data["camera"]  # Orthority's legacy config.yaml
    if isinstance(data, dict) and "type" in data and not isinstance(data["type"], dict):
        data = {str(data.get("name", "camera")): data}  # one camera, not nested
    if not isinstance(data, dict) or not data or not all(isinstance(v, dict) for v in data.values()):
        raise RiverbedError("not an Orthority interior parameter file (expected camera IDs, each with type, "
                            "im_size, focal_len, ...)", path)
    cameras = {}
    for cam_id, params in data.items():
        key = f"{cam_id}."
        for required in ("type", "im_size", "focal_len"):
            if params.get(required) is None:
                raise RiverbedError(f"{key}{required}: missing", path)
        model = str(params["type"]).lower()
        if model not in ORTHORITY_COEFFS:
            raise RiverbedError(f"{key}type: camera model {params['type']!r} is not supported (riverbed reads "
                                "pinhole, brown and opencv: OpenCV's Brown model, no fisheye)", path)
        allowed = ORTHORITY_KEYS + ORTHORITY_COEFFS[model]
        unknown = [str(k) for k in params if k not in allowed]
        if unknown:
            raise RiverbedError(f"{key}{unknown[0]}: unknown key for a {model} camera (keys: {', '.join(allowed)})",
                                path)
        width, height = image_size(params["im_size"], f"{key}im_size", path)
        side = max(width, height)
        focal = params["focal_len"]
        focal = focal if isinstance(focal, (list, tuple)) else [focal, focal]
        if len(focal) != 2:
            raise RiverbedError(f"{key}focal_len: expected a number or [fx, fy], got {params['focal_len']!r}", path)
        if params.get("sensor_size") is not None:
            sw, sh = numbers(params["sensor_size"], 2, f"{key}sensor_size", path, positive=True)
            fx, fy = numbers(focal, 2, f"{key}focal_len", path, positive=True)
            fx, fy = fx * width / sw, fy * height / sh
        else:
            hint = "give sensor_size in the units of focal_len"
            fx, fy = (side * normalised_focal(f, f"{key}focal_len", path, hint) for f in focal)
        f = square_focal(fx, fy, f"{key}focal_len", path)
        cx = (width - 1) / 2 + side * number(params.get("cx", 0.0), f"{key}cx", path)
        cy = (height - 1) / 2 + side * number(params.get("cy", 0.0), f"{key}cy", path)
        coeffs = {k: number(params[k], f"{key}{k}", path) for k in ORTHORITY_COEFFS[model] if k in params}
        cameras[str(cam_id)] = interior(f, cx, cy, distortion_coefficients(coeffs, key, path), width, height,
                                        f"{key}focal_len", path)
    return cameras


def _camera_of(cameras, cam_id, key, interior_path, path):
    if cam_id is None or cam_id == "":
        if len(cameras) == 1:
            return next(iter(cameras.values()))
        raise RiverbedError(f"{key}: no camera given, and {Path(interior_path).name} has {len(cameras)} cameras",
                            path)
    if cam_id not in cameras:
        raise RiverbedError(f"{key}: camera {cam_id!r} is not in {Path(interior_path).name} (it has: "
                            f"{', '.join(cameras)})", path)
    return cameras[cam_id]


def _check_angles(values, radians, key, path):
    """Angles in degrees, from degrees or radians; a value outside one turn is a unit mistake."""
    limit = 2 * math.pi if radians else 360.0
    for a in values:
        if abs(a) > limit + 1e-9:
            unit = "radians (are they degrees?)" if radians else "degrees"
            raise RiverbedError(f"{key}: {a!r} is outside +-{limit:.6g}: not an angle in {unit}", path)
    return [math.degrees(a) for a in values] if radians else list(values)


def _csv_dialect(text, lines, path):
    """The CSV's delimiter (comma, semicolon, colon, space or tab) and quote character, as Orthority detects them
    (Python's sniffer); from the first line alone when the rows disagree (a short row is then reported by line)."""
    first = next((line for line in lines if line.strip()), "")
    for sample in (text[:10000], first):
        try:
            dialect = csv.Sniffer().sniff(sample, delimiters=",;: \t")
        except csv.Error:
            continue
        dialect.skipinitialspace = True
        return dialect
    raise RiverbedError("not a CSV exterior parameter file (cannot tell its delimiter: comma, semicolon, colon, space "
                        "or tab)", path)


def read_orthority_csv(path, cameras, interior_path, *, crs=None, radians=False):
    """Frames of an Orthority CSV exterior parameter file (see :func:`read_orthority`)."""
    path = Path(path)
    text = read_text(path, "CSV exterior parameter file", MAX_EXPORT_BYTES).lstrip("\ufeff")
    lines = text.splitlines()
    dialect = _csv_dialect(text, lines, path)
    try:
        rows = [(n, row) for n, row in enumerate(csv.reader(lines, dialect), 1) if any(c.strip() for c in row)]
    except csv.Error as e:
        raise RiverbedError(f"not a CSV exterior parameter file ({e})", path) from None
    if not rows:
        raise RiverbedError("no rows", path)
    first = [c.strip().lower() for c in rows[0][1]]
    fields, rows = (first, rows[1:]) if "filename" in first else (list(LEGACY_FIELDS), rows)
    xyz, lla = {"x", "y", "z"} <= set(fields), {"latitude", "longitude", "altitude"} <= set(fields)
    opk, rpy = {"omega", "phi", "kappa"} <= set(fields), {"roll", "pitch", "yaw"} <= set(fields)
    if "filename" not in fields or not (xyz or lla) or not (opk or rpy):
        raise RiverbedError("header: needs filename, x y z (or latitude longitude altitude) and omega phi kappa "
                            f"(or roll pitch yaw); it has {', '.join(fields)}", path)
    if crs is not None:
        target = projected_crs(crs, "--crs", None)
    elif xyz and path.with_suffix(".prj").is_file():
        prj = path.with_suffix(".prj")
        target = projected_crs(read_text(prj, "CRS file", MAX_SMALL_BYTES), "CRS", prj)
    else:
        target = None
    if target is None and (rpy or lla):
        if xyz or opk:
            what = "roll, pitch, yaw need the CRS of x, y, z" if xyz else \
                "latitude, longitude with omega, phi, kappa need the projected CRS the angles refer to"
            raise RiverbedError(f"{what}: give --crs" + (" or a .prj file beside the CSV" if xyz else ""), path)
        lat_lon = [[number(dict(zip(fields, r)).get(k), f"line {n}: {k}", path) for k in ("latitude", "longitude")]
                   for n, r in rows if len(r) >= len(fields)]
        target = utm_crs(*np.mean(lat_lon, axis=0)) if lat_lon else None
    to_grid = geodetic_to_grid(target) if lla else None
    to_lla = geodetic_to_grid(LLA_CRS, target) if (xyz and rpy) else None
    frames = {}
    for n, row in rows:
        if len(row) < len(fields) or any(c.strip() for c in row[len(fields):]):
            raise RiverbedError(f"line {n}: expected {len(fields)} fields ({', '.join(fields)}), got {len(row)}",
                                path)
        values = dict(zip(fields, (c.strip() for c in row)))
        name = Path(values["filename"]).name
        if not name:
            raise RiverbedError(f"line {n}: filename: empty", path)
        if name in frames:
            raise RiverbedError(f"line {n}: filename {name!r} given twice", path)
        inner = _camera_of(cameras, values.get("camera"), f"line {n}: camera", interior_path, path)
        keys = ("x", "y", "z") if xyz else ("longitude", "latitude", "altitude")
        position = [number(values[k], f"line {n}: {k}", path) for k in keys]
        angle_keys = ("omega", "phi", "kappa") if opk else ("roll", "pitch", "yaw")
        angles = _check_angles([number(values[k], f"line {n}: {k}", path) for k in angle_keys], radians,
                               f"line {n}: {'/'.join(angle_keys)}", path)
        where = f"line {n}: position"
        centre = position if xyz else transform_points(to_grid, position, where, path)[0]
        if opk:
            M = opk_to_matrix(*angles)
        else:
            lon, lat, alt = position if lla else transform_points(to_lla, position, where, path)[0]
            M = rpy_camera_to_grid(lat, lon, alt, *angles, target, LLA_CRS, where, path)
        frames[name] = frame(inner, M, centre, target, path)
    return frames


def read_orthority_geojson(path, cameras, interior_path, *, crs=None):
    """Frames of an Orthority GeoJSON exterior parameter file (see :func:`read_orthority`)."""
    data = load_text_data(path, "Orthority exterior parameter file", MAX_EXPORT_BYTES, fmt="json")[0]
    if not isinstance(data, dict) or data.get("type") != "FeatureCollection":
        raise RiverbedError("not an Orthority exterior parameter file (expected a GeoJSON FeatureCollection)", path)
    if crs is not None:
        target = projected_crs(crs, "--crs", None)
    elif data.get("world_crs") is None:
        raise RiverbedError("world_crs: missing (the CRS of xyz); give --crs", path)
    else:
        target = projected_crs(data["world_crs"], "world_crs", path)
    features = data.get("features")
    if not isinstance(features, list):
        raise RiverbedError("features: expected a list of GeoJSON Features", path)
    frames = {}
    for i, feature in enumerate(features):
        key = f"features[{i}].properties"
        props = feature.get("properties") if isinstance(feature, dict) else None
        if not isinstance(props, dict):
            raise RiverbedError(f"{key}: missing", path)
        name = props.get("filename")
        if not isinstance(name, str) or not Path(name).name:
            raise RiverbedError(f"{key}.filename: expected an image file name, got {name!r}", path)
        name = Path(name).name
        if name in frames:
            raise RiverbedError(f"{key}.filename: {name!r} given twice", path)
        inner = _camera_of(cameras, props.get("camera"), f"{key}.camera", interior_path, path)
        for k in ("xyz", "opk"):
            if props.get(k) is None:
                raise RiverbedError(f"{key}.{k}: missing", path)
        centre = numbers(props["xyz"], 3, f"{key}.xyz", path)
        angles = _check_angles(numbers(props["opk"], 3, f"{key}.opk", path), True, f"{key}.opk", path)
        frames[name] = frame(inner, opk_to_matrix(*angles), centre, target, path)
    return frames


def read_orthority(interior_path, exterior_path, *, crs=None, radians=False):
    """``{image name: FrameOrientation}`` from Orthority's interior YAML and exterior CSV or GeoJSON.

    Parameters
    ----------
    interior_path, exterior_path : path-like
        The exterior file is GeoJSON when its name ends in ``.geojson`` or ``.json``, CSV otherwise.
    crs : str, optional
        The projected CRS of ``x, y, z`` (replacing a ``.prj`` beside the CSV or the GeoJSON's ``world_crs``), or
        the one latitudes and longitudes are projected into (default for latitude/longitude with roll/pitch/yaw:
        the UTM zone of their mean).
    radians : bool
        The CSV's angles are in radians (GeoJSON's always are).
    """
    cameras = read_orthority_interior(interior_path)
    if Path(exterior_path).suffix.lower() in (".geojson", ".json"):
        return read_orthority_geojson(exterior_path, cameras, interior_path, crs=crs)
    return read_orthority_csv(exterior_path, cameras, interior_path, crs=crs, radians=radians)
