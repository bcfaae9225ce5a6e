"""RPC camera models of satellite images: reading every common format, projection, localisation, DEMs.

Reading goes through libraries, never a parser of riverbed's own (``docs/rpc.md`` compares them):

- **GDAL** (through rasterio) reads the RPCs of an image (GeoTIFF RPC tags, and the sidecar files GDAL finds next
  to it) and, through its metadata readers, the sidecar files users bring alone: RPC00B text (``*_RPC.TXT``:
  IKONOS, Planet, SkySat), DigitalGlobe ``.RPB`` and ``.XML`` (WorldView, QuickBird, GeoEye), DIMAP v2/v3
  ``RPC_*.XML`` (Pléiades, SPOT 6/7, Pléiades Neo). GDAL finds a sidecar only beside an image of a matching name,
  so :func:`read_rpc` copies the file under that name beside a 1 x 1 placeholder GeoTIFF in a temporary folder.
- **shareloc** (CNES) reads OSSIM keyword lists (``.geom``) and DIMAP v1 (SPOT 5), which GDAL does not read alone.
- rpcm's JSON (its ``RPCModel.__dict__``, e.g. the DFC2019 ``JAX_*.json``) is read with :mod:`json`; riverbed only
  maps its key names.

Conventions (riverbed's everywhere, and the RPC00B standard's):

- **Pixels**: image coordinates ``(col, row)``, float64, with the centre of the first (top-left) pixel at
  ``(0, 0)``; the pixel covers ``[-0.5, 0.5)``. GDAL's RPC metadata, OSSIM and rpcm use the same convention (GDAL
  and rpcm subtract 1 from DIMAP v2's 1-based offsets). shareloc, with its default ``topleftconvention=True``,
  puts ``(0, 0)`` at the top-left *corner* (its offsets are 0.5 larger); GDAL's RPC *transformer* works in GDAL
  raster space, whose ``(0, 0)`` is also the corner. riverbed reads shareloc with ``topleftconvention=False``.
- **Ground**: longitude and latitude in degrees on WGS 84 (EPSG:4326), heights in metres above the WGS 84
  ellipsoid (EPSG:4979), as RPCs are fitted. A DEM in orthometric heights (SRTM: EGM96) is converted to
  ellipsoidal heights through pyproj (:func:`riverbed_cli.geometry.rpc_dem.read_dem`).
- **Localisation** inverts the projection (ground -> image) by Newton's method in float64, to 1e-9 px; the
  image -> ground polynomials some files also carry (DIMAP's direct model) are an approximation of that inverse
  (errors of 1e-2 px and more) and are not used, so ``project(localize(col, row, h), h) == (col, row)``.
"""

import shutil
import tempfile
import warnings
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import rasterio
from numba import prange
from rasterio.errors import NotGeoreferencedWarning, RasterioIOError
from rasterio.rpc import RPC

from ..errors import RiverbedError
from ..io.paths import require_file
from ..io.textfiles import parse_json
from ..runtime.kernel import kernel

#: RPC files larger than this are refused before parsing (WorldView-1's XML, the largest sample, is 0.7 MB).
MAX_RPC_BYTES = 20_000_000

#: The exponents (lon, lat, height) of the 20 terms of an RPC00B cubic, in the standard order (NITF RPC00B,
#: GDAL, OSSIM, rpcm): 1, L, P, H, LP, LH, PH, L², P², H², PLH, L³, LP², LH², L²P, P³, PH², L²H, P²H, H³.
RPC_TERMS = np.array([
    (0, 0, 0), (1, 0, 0), (0, 1, 0), (0, 0, 1), (1, 1, 0), (1, 0, 1), (0, 1, 1), (2, 0, 0), (0, 2, 0), (0, 0, 2),
    (1, 1, 1), (3, 0, 0), (1, 2, 0), (1, 0, 2), (2, 1, 0), (0, 3, 0), (0, 1, 2), (2, 0, 1), (0, 2, 1), (0, 0, 3),
])

#: The scalar fields of an RPC model, as GDAL's RPC metadata names them (upper case in the file).
OFFSET_KEYS = ("line_off", "samp_off", "lat_off", "long_off", "height_off",
               "line_scale", "samp_scale", "lat_scale", "long_scale", "height_scale")
COEFF_KEYS = ("line_num_coeff", "line_den_coeff", "samp_num_coeff", "samp_den_coeff")

#: rpcm's JSON / ``RPCModel.__dict__`` names -> GDAL's names.
RPCM_KEYS = {"row_offset": "line_off", "col_offset": "samp_off", "lat_offset": "lat_off", "lon_offset": "long_off",
             "alt_offset": "height_off", "row_scale": "line_scale", "col_scale": "samp_scale",
             "lat_scale": "lat_scale", "lon_scale": "long_scale", "alt_scale": "height_scale",
             "row_num": "line_num_coeff", "row_den": "line_den_coeff", "col_num": "samp_num_coeff",
             "col_den": "samp_den_coeff"}

#: shareloc's rpc dict names -> GDAL's names (shareloc's x is longitude, y latitude).
SHARELOC_KEYS = {"offset_row": "line_off", "offset_col": "samp_off", "offset_y": "lat_off", "offset_x": "long_off",
                 "offset_alt": "height_off", "scale_row": "line_scale", "scale_col": "samp_scale",
                 "scale_y": "lat_scale", "scale_x": "long_scale", "scale_alt": "height_scale",
                 "num_row": "line_num_coeff", "den_row": "line_den_coeff", "num_col": "samp_num_coeff",
                 "den_col": "samp_den_coeff"}

NEWTON_TOL_PX = 1e-9
NEWTON_MAX_ITER = 30


@kernel(parallel=True)
def _rational_kernel(L, P, H, coef, expo, derivatives, out):
    # Per point: the column and row ratios N/D of the 20-term polynomials (coef rows: samp num, samp den, line num,
    # line den) and, with derivatives, their partial derivatives in L and P. out: (6, N) = q_s, dq_s/dL, dq_s/dP,
    # q_r, dq_r/dL, dq_r/dP. One pass per point, no (20, N) temporaries: triangulating a 500 x 500 map projects
    # millions of points.
    n = L.shape[0]
    for i in prange(n):
        lp = np.empty(4, np.float64)
        pp = np.empty(4, np.float64)
        hp = np.empty(4, np.float64)
        lp[0] = 1.0
        pp[0] = 1.0
        hp[0] = 1.0
        for j in range(1, 4):
            lp[j] = lp[j - 1] * L[i]
            pp[j] = pp[j - 1] * P[i]
            hp[j] = hp[j - 1] * H[i]
        acc = np.zeros(12, np.float64)  # value, d/dL, d/dP of each of the 4 polynomials
        for k in range(20):
            ea, eb, ec = expo[k, 0], expo[k, 1], expo[k, 2]
            ph = pp[eb] * hp[ec]
            t = lp[ea] * ph
            tl = ea * lp[ea - 1] * ph if ea > 0 else 0.0
            tp = eb * lp[ea] * pp[eb - 1] * hp[ec] if eb > 0 else 0.0
            for m in range(4):
                acc[3 * m] += coef[m, k] * t
                if derivatives:
                    acc[3 * m + 1] += coef[m, k] * tl
                    acc[3 * m + 2] += coef[m, k] * tp
        for side in range(2):
            nu = 3 * (2 * side)
            de = nu + 3
            q = acc[nu] / acc[de]
            out[3 * side, i] = q
            if derivatives:
                out[3 * side + 1, i] = (acc[nu + 1] - q * acc[de + 1]) / acc[de]
                out[3 * side + 2, i] = (acc[nu + 2] - q * acc[de + 2]) / acc[de]


@dataclass(frozen=True)
class RPCModel:
    """A rational polynomial camera: ground (lon, lat, ellipsoidal height) -> image (col, row), float64.

    ``col = samp_off + samp_scale * N_s(L, P, H) / D_s(L, P, H)`` (and ``row`` likewise with the line
    polynomials), with ``L = (lon - long_off) / long_scale``, ``P = (lat - lat_off) / lat_scale``,
    ``H = (h - height_off) / height_scale``; pixel centres at integer coordinates, ``(0, 0)`` the centre of the
    first pixel (module docstring). Offsets in pixels, degrees and metres; coefficients unitless.
    """

    line_off: float
    samp_off: float
    lat_off: float
    long_off: float
    height_off: float
    line_scale: float
    samp_scale: float
    lat_scale: float
    long_scale: float
    height_scale: float
    line_num_coeff: tuple
    line_den_coeff: tuple
    samp_num_coeff: tuple
    samp_den_coeff: tuple
    source: str = field(default="", compare=False)
    format: str = field(default="", compare=False)

    @classmethod
    def from_dict(cls, d, source="", fmt=""):
        """From a mapping with GDAL's RPC names (any case; coefficients as 20 numbers or a space-separated string).

        Raises :class:`RiverbedError` naming ``source`` for a missing or non-numeric field, a coefficient list
        that is not 20 finite numbers, or a zero scale.
        """
        low = {str(k).lower(): v for k, v in d.items()}
        if "lon_off" in low and "long_off" not in low:
            low["long_off"], low["long_scale"] = low.get("lon_off"), low.get("lon_scale")
        fields = {}
        for key in OFFSET_KEYS:
            if low.get(key) is None:
                raise RiverbedError(f"not a complete RPC model: {key.upper()} missing", source or None)
            try:
                value = float(str(low[key]).split()[0]) if isinstance(low[key], str) else float(low[key])
            except (ValueError, IndexError, TypeError):
                raise RiverbedError(f"{key.upper()}: not a number ({low[key]!r})", source or None) from None
            if not np.isfinite(value) or (key.endswith("scale") and value == 0):
                raise RiverbedError(f"{key.upper()}: must be finite{' and non-zero' * key.endswith('scale')}, "
                                    f"got {value}", source or None)
            fields[key] = value
        for key in COEFF_KEYS:
            raw = low.get(key)
            if raw is None:
                raise RiverbedError(f"not a complete RPC model: {key.upper()} missing", source or None)
            try:
                coeffs = tuple(float(v) for v in (raw.split() if isinstance(raw, str) else raw))
            except (ValueError, TypeError):
                raise RiverbedError(f"{key.upper()}: not a list of numbers", source or None) from None
            if len(coeffs) != 20:
                raise RiverbedError(f"{key.upper()}: expected 20 coefficients, got {len(coeffs)}", source or None)
            if not np.all(np.isfinite(coeffs)):
                bad = int(np.count_nonzero(~np.isfinite(coeffs)))
                raise RiverbedError(f"{key.upper()}: {bad} of the 20 coefficients {'is' if bad == 1 else 'are'} not "
                                    "finite", source or None)
            fields[key] = coeffs
        if fields["line_den_coeff"][0] == 0 or fields["samp_den_coeff"][0] == 0:
            raise RiverbedError("RPC denominator with a zero constant term", source or None)
        return cls(**fields, source=str(source), format=fmt)

    def to_dict(self):
        """GDAL's RPC metadata names (upper case) -> numbers and 20-number lists: what a pair file records."""
        out = {k.upper(): getattr(self, k) for k in OFFSET_KEYS}
        out.update({k.upper(): list(getattr(self, k)) for k in COEFF_KEYS})
        return out

    def to_gdal(self):
        """A :class:`rasterio.rpc.RPC` of this model (GDAL's RPC metadata, for GeoTIFF tags or GDAL's transformer)."""
        return RPC(err_bias=None, err_rand=None, **{k: getattr(self, k) for k in OFFSET_KEYS},
                                **{k: list(getattr(self, k)) for k in COEFF_KEYS})

    def shifted(self, col0, row0):
        """The model of a crop whose pixel (0, 0) is this image's pixel ``(col0, row0)``."""
        return replace(self, samp_off=self.samp_off - float(col0), line_off=self.line_off - float(row0))

    def _normalised(self, lon, lat, h):
        lon, lat, h = np.broadcast_arrays(*(np.asarray(v, dtype=np.float64) for v in (lon, lat, h)))
        return ((lon - self.long_off) / self.long_scale, (lat - self.lat_off) / self.lat_scale,
                (h - self.height_off) / self.height_scale)

    def _rational(self, L, P, H, derivatives=False):
        # the column and row ratios (and their derivatives in L and P) at normalised coordinates, any shape
        shape = np.shape(L)
        flat = [np.ascontiguousarray(np.ravel(v), dtype=np.float64) for v in (L, P, H)]
        coef = np.array([self.samp_num_coeff, self.samp_den_coeff, self.line_num_coeff, self.line_den_coeff],
                        dtype=np.float64)
        out = np.empty((6, flat[0].size), np.float64)
        _rational_kernel(*flat, coef, RPC_TERMS, bool(derivatives), out)
        out = out.reshape((6,) + shape)
        if derivatives:
            return [(out[0], out[1], out[2]), (out[3], out[4], out[5])]
        return [out[0], out[3]]

    def project(self, lon, lat, h):
        """Ground -> image: ``(col, row)`` in pixels (float64 arrays of the broadcast shape).

        Parameters
        ----------
        lon, lat : array_like
            WGS 84 longitude and latitude (degrees).
        h : array_like
            Height above the WGS 84 ellipsoid (m).
        """
        L, P, H = self._normalised(lon, lat, h)
        s, r = self._rational(L, P, H)
        return self.samp_off + self.samp_scale * s, self.line_off + self.line_scale * r

    def localize(self, col, row, h):
        """Image + height -> ground: ``(lon, lat)`` in degrees with ``project(lon, lat, h) == (col, row)``.

        Newton's method on the projection from the model's centre, until the step is below 1e-9 px (at most 30
        iterations; points that do not converge, e.g. far outside the model's domain, come back NaN).

        Parameters
        ----------
        col, row : array_like
            Image coordinates (px, pixel centres at integers).
        h : array_like
            Height above the WGS 84 ellipsoid (m).
        """
        col, row, h = np.broadcast_arrays(*(np.asarray(v, dtype=np.float64) for v in (col, row, h)))
        shape = col.shape
        cn = ((col - self.samp_off) / self.samp_scale).ravel()
        rn = ((row - self.line_off) / self.line_scale).ravel()
        H = ((h - self.height_off) / self.height_scale).ravel()
        L = np.zeros_like(cn)
        P = np.zeros_like(cn)
        done = np.zeros(cn.shape, bool)
        tol = NEWTON_TOL_PX / max(abs(self.samp_scale), abs(self.line_scale))
        for _ in range(NEWTON_MAX_ITER):
            todo = ~done
            if not todo.any():
                break
            with np.errstate(all="ignore"):     # points diverging far outside the domain end as NaN
                (s, sL, sP), (r, rL, rP) = self._rational(L[todo], P[todo], H[todo], derivatives=True)
                es, er = s - cn[todo], r - rn[todo]
                det = sL * rP - sP * rL
                dL = (rP * es - sP * er) / det
                dP = (sL * er - rL * es) / det
            L[todo] -= dL
            P[todo] -= dP
            step = np.maximum(np.abs(dL), np.abs(dP))
            conv = step < tol
            bad = ~np.isfinite(step)
            idx = np.flatnonzero(todo)
            done[idx[conv | bad]] = True
            L[idx[bad]] = np.nan
        L[~done] = np.nan
        P[~done | np.isnan(L)] = np.nan
        lon = self.long_off + self.long_scale * L
        lat = self.lat_off + self.lat_scale * P
        return lon.reshape(shape), lat.reshape(shape)

    def localize_dem(self, col, row, dem, max_iter=100, tol_m=1e-4):
        """Image -> ground on a DEM: ``(lon, lat, h)``, h the DEM's ellipsoidal height at (lon, lat).

        Fixed-point iteration ``h <- dem(localize(col, row, h))`` from the DEM's mean height (the usual method: it
        converges where the terrain's slope times the tangent of the viewing angle is below 1); points still
        moving after ``max_iter`` iterations are found by bisection of ``dem(localize(h)) - h`` between the DEM's
        lowest and highest heights. Points whose line of sight leaves the DEM come back NaN.

        Parameters
        ----------
        col, row : array_like
            Image coordinates (px).
        dem : DEM
            From :func:`read_dem` (ellipsoidal heights).
        max_iter : int
            Fixed-point iterations before bisection.
        tol_m : float
            Height tolerance (m).
        """
        col, row = np.broadcast_arrays(np.asarray(col, np.float64), np.asarray(row, np.float64))
        shape = col.shape
        col, row = col.ravel(), row.ravel()
        h = np.full(col.shape, dem.mean_height)
        done = np.zeros(col.shape, bool)
        for _ in range(max_iter):
            todo = np.flatnonzero(~done)
            if todo.size == 0:
                break
            lon, lat = self.localize(col[todo], row[todo], h[todo])
            hn = dem.height(lon, lat)
            conv = np.abs(hn - h[todo]) < tol_m
            h[todo] = hn
            done[todo[conv | np.isnan(hn)]] = True
        todo = np.flatnonzero(~done)
        if todo.size:
            lo = np.full(todo.size, dem.min_height - 1.0)
            hi = np.full(todo.size, dem.max_height + 1.0)
            while np.max(hi - lo) > tol_m:
                mid = 0.5 * (lo + hi)
                g = dem.height(*self.localize(col[todo], row[todo], mid)) - mid
                above = g > 0          # the terrain is above mid: the intersection is higher
                lo = np.where(above, mid, lo)
                hi = np.where(above, hi, mid)
                if np.isnan(g).all():
                    break
            h[todo] = 0.5 * (lo + hi)
        lon, lat = self.localize(col, row, h)
        bad = np.isnan(dem.height(lon, lat)) | np.isnan(h)
        lon[bad] = lat[bad] = h[bad] = np.nan
        return lon.reshape(shape), lat.reshape(shape), h.reshape(shape)


# ---------------------------------------------------------------------------------------------------------------
# reading


def _gdal_rpcs(path):
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", NotGeoreferencedWarning)
            with rasterio.open(path) as ds:
                rpcs = ds.rpcs
    except RasterioIOError as e:
        raise RiverbedError(f"cannot read ({str(e).splitlines()[0]})", path) from None
    return None if rpcs is None else rpcs.to_dict()


def _gdal_sidecar(path, image_name, sidecar_name):
    """GDAL's reading of an RPC sidecar file: the file copied as ``sidecar_name`` beside a 1 x 1 GeoTIFF."""
    with tempfile.TemporaryDirectory(prefix="riverbed-rpc-") as tmp:
        image = Path(tmp) / image_name
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", NotGeoreferencedWarning)
            with rasterio.open(image, "w", driver="GTiff", width=1, height=1, count=1, dtype="uint8") as ds:
                ds.write(np.zeros((1, 1, 1), np.uint8))
        shutil.copyfile(path, Path(tmp) / sidecar_name)
        return _gdal_rpcs(image)


def _xml_root(path, text):
    try:
        parser = ET.XMLPullParser(events=("start",))
        parser.feed(text)
        for _, elem in parser.read_events():
            return elem
    except ET.ParseError as e:
        raise RiverbedError(f"not an RPC file (invalid XML: {e})", path) from None
    raise RiverbedError("not an RPC file (empty XML)", path)


def _dimap_version(root):
    fmt = root.find("Metadata_Identification/METADATA_FORMAT")
    if fmt is None:
        return None
    return fmt.get("version") or (fmt.text or "").strip()


def _read_shareloc(path, what):
    # shareloc (numba, its C++ bindings: 1.3 s) loads only for the two formats GDAL does not read
    from shareloc.geomodels.rpc_readers import rpc_reader_dimap_v1, rpc_reader_ossim_kwl

    reader = rpc_reader_ossim_kwl if what == "ossim" else rpc_reader_dimap_v1
    try:
        params = reader(str(path), topleftconvention=False)
    except (KeyError, ValueError, IndexError, AttributeError) as e:
        raise RiverbedError(f"not a complete {what} RPC model ({type(e).__name__}: {e})", path) from None
    return {SHARELOC_KEYS[k]: v for k, v in params.items() if k in SHARELOC_KEYS}


def _read_json(path, text):
    data = parse_json(text, path)
    if isinstance(data, dict) and isinstance(data.get("rpc"), dict):
        data = data["rpc"]
    if not isinstance(data, dict):
        raise RiverbedError("not an RPC file (JSON without an RPC mapping)", path)
    if "row_offset" in data:
        return {RPCM_KEYS[k]: v for k, v in data.items() if k in RPCM_KEYS}, "rpcm-json"
    if any(str(k).lower() == "line_off" for k in data):
        return data, "json"
    raise RiverbedError("not an RPC file (JSON with neither rpcm's row_offset nor GDAL's LINE_OFF keys)", path)


def read_rpc(path):
    """The RPC model of ``path``: an image with RPCs, or an RPC file alone (module docstring lists the formats).

    The format is recognised from the content, not the name: TIFF (and other rasters GDAL opens) -> its RPC
    metadata; JSON -> rpcm's (or GDAL's) names; XML with a ``Dimap_Document`` root -> DIMAP (v2/v3 through GDAL,
    v1 through shareloc); XML with an ``isd`` root -> DigitalGlobe (GDAL); text with ``BEGIN_GROUP = IMAGE`` ->
    ``.RPB`` (GDAL); text with ``type: ossim...`` -> OSSIM ``.geom`` (shareloc); text with ``LINE_OFF:`` -> RPC00B
    text (GDAL). Returns an :class:`RPCModel` whose ``format`` names the reader.

    Raises :class:`RiverbedError` (one line, naming the file) for a missing, unreadable, oversized, unsupported or
    incomplete file.
    """
    path = require_file(path)
    size = path.stat().st_size
    with path.open("rb") as f:
        head = f.read(4096)
    text = None
    if size <= MAX_RPC_BYTES and b"\x00" not in head:
        with path.open("rb") as f:
            raw = f.read(MAX_RPC_BYTES + 1)  # bounded even if the file grew since its size was read
        try:
            text = raw.decode("utf-8-sig") if len(raw) <= MAX_RPC_BYTES else None
        except UnicodeDecodeError:
            text = None
    if text is None:
        try:
            d = _gdal_rpcs(path)
        except RiverbedError:
            raise RiverbedError("not an RPC file (neither an image GDAL reads nor RPC text)", path) from None
        if not d:
            raise RiverbedError("no RPC in this image (no RPC tags, no RPC sidecar file beside it)", path)
        return RPCModel.from_dict(d, path, "gdal-image")
    stripped = text.lstrip()
    if stripped.startswith("{"):
        d, fmt = _read_json(path, text)
        return RPCModel.from_dict(d, path, fmt)
    if stripped.startswith("<"):
        root = _xml_root(path, text)
        tag = root.tag.split("}")[-1]
        if tag == "Dimap_Document":
            tree = ET.fromstring(text)
            version = _dimap_version(tree)
            if version is not None and version.replace(".", "", 1).isdigit() and float(version) < 2:
                return RPCModel.from_dict(_read_shareloc(path, "DIMAP v1"), path, "dimap-v1-shareloc")
            d = _gdal_sidecar(path, "IMG_RIVERBED_R1C1.tif", "RPC_RIVERBED.XML")
            if not d:
                raise RiverbedError("a DIMAP file without an RPC model GDAL reads (no Rational_Function_Model)",
                                    path)
            return RPCModel.from_dict(d, path, "dimap-gdal")
        if tag == "isd":
            d = _gdal_sidecar(path, "riverbed.tif", "riverbed.XML")
            if not d:
                raise RiverbedError("a DigitalGlobe XML file without an RPB block GDAL reads", path)
            return RPCModel.from_dict(d, path, "digitalglobe-xml-gdal")
        raise RiverbedError(f"unsupported RPC XML (root element <{tag}>; riverbed reads DIMAP <Dimap_Document> and "
                            "DigitalGlobe <isd> files)", path)
    lines = [ln.strip() for ln in text.splitlines()]
    if any(ln.replace(" ", "").upper().startswith("BEGIN_GROUP=IMAGE") for ln in lines):
        d = _gdal_sidecar(path, "riverbed.tif", "riverbed.RPB")
        if not d:
            raise RiverbedError("an RPB file GDAL cannot read (incomplete IMAGE group)", path)
        return RPCModel.from_dict(d, path, "rpb-gdal")
    if any(ln.startswith("type:") and "ossim" in ln for ln in lines):
        return RPCModel.from_dict(_read_shareloc(path, "ossim"), path, "ossim-geom-shareloc")
    if any(ln.upper().startswith("LINE_OFF:") for ln in lines):
        d = _gdal_sidecar(path, "riverbed.tif", "riverbed_RPC.TXT")
        if not d:
            raise RiverbedError("an RPC text file GDAL cannot read (RPC00B keys missing)", path)
        return RPCModel.from_dict(d, path, "rpc-txt-gdal")
    raise RiverbedError("not an RPC file (no RPC tags, DIMAP, DigitalGlobe, RPB, OSSIM .geom, RPC00B text or rpcm "
                        "JSON content)", path)
