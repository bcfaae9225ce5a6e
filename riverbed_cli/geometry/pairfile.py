"""Read and write pair files: the one description of a rectified pair's geometry (YAML or JSON).

```yaml
left: im0.png            # optional; paths are relative to the pair file
right: im1.png
width: 2964              # optional image size (px); read from the left image when needed and absent
height: 1988
P_left:  [[f, 0, cx, 0], [0, f, cy, 0], [0, 0, 1, 0]]   # 3x4, world minus origin -> left pixels
P_right: [[f, 0, cx1, -f*B], [0, f, cy, 0], [0, 0, 1, 0]]
origin: [x0, y0, z0]     # optional, default 0: subtracted from world coordinates before any projection
crs: EPSG:32632          # optional: CRS of world coordinates
registration: [[...4...], [...4...], [...4...], [0, 0, 0, 1]]   # optional LiDAR -> world (default identity)
disparity: [435, 466]    # optional: the pair's disparity range (px; riverbed rectify, from tie points)
```

A pair file with an ``rpc:`` key is an *RPC pair* (``riverbed rectify --rpc``; its keys in
:mod:`riverbed_cli.geometry.rpc_pair`): :func:`load_pairfile` reads it into an
:class:`~riverbed_cli.geometry.rpc_pair.RPCPair` (``kind == "rpc"``) only when asked (``accept_rpc=True``, as
``riverbed project``, ``dsm`` and ``block`` do); a caller that needs a pinhole pair refuses it in one line.

Both formats go through :func:`load_pairfile`: ``.json`` files (or text starting with ``{``) with :mod:`json`,
everything else with ``yaml.safe_load`` (never the unsafe loader: pair files come from strangers), both within
the size, nesting and alias bounds of :mod:`riverbed_cli.io.textfiles`. Errors are one line naming the file and the
key. See :mod:`riverbed_cli.geometry.cameras` for the rectified-pair rule.
"""

import json
import os
from pathlib import Path

import numpy as np
import yaml
from pyproj import CRS
from pyproj.exceptions import CRSError

from ..errors import RiverbedError
from ..io.atomic import atomic_output
from ..io.textfiles import load_text_data
from .cameras import PairGeometry, as_matrix, check_registration
from .rpc_pair import relative_path, rpc_pair_from_dict

#: Pair files and registration files larger than this are refused before parsing.
MAX_BYTES = 1_000_000
KEYS = ("left", "right", "width", "height", "P_left", "P_right", "origin", "crs", "registration", "disparity")
#: Who needs a pinhole pair file, when the caller does not say (named when an RPC pair file reaches it).
RPC_REFUSERS = "this use"


def _parse(path, what):
    # JSON for a .json name or text starting with "{", YAML otherwise; sizes, nesting and aliases bounded
    return load_text_data(Path(path), what, MAX_BYTES)


def _check_crs(crs, path):
    try:
        CRS.from_user_input(crs)
    except CRSError:
        raise RiverbedError(f"crs: unknown CRS '{crs}'", path) from None


def load_pairfile(path, accept_rpc=False, command=None):
    """Read a pair file (YAML or JSON) into a validated :class:`PairGeometry` (or an RPC pair).

    Image paths are resolved relative to the pair file's folder. Raises :class:`RiverbedError` (``PATH: KEY:
    problem``) for a missing or unreadable file, unknown keys, wrong shapes, non-finite numbers, a pair that
    is not rectified, or a singular registration.

    Parameters
    ----------
    path : str or Path
        The pair file.
    accept_rpc : bool
        Return an :class:`~riverbed_cli.geometry.rpc_pair.RPCPair` for a file with an ``rpc:`` key; otherwise
        such a file is a one-line error ("an RPC pair file: COMMAND needs a pinhole pair file (P_left, P_right)").
    command : str, optional
        What is named in that error (default "this use").
    """
    path = Path(path)
    data, _ = _parse(path, "pair file")
    if not isinstance(data, dict):
        raise RiverbedError("not a pair file (expected a mapping with P_left and P_right)", path)
    if "rpc" in data:
        if not accept_rpc:
            raise RiverbedError(f"an RPC pair file: {command or RPC_REFUSERS} needs a pinhole pair file (P_left, "
                                "P_right)", path)
        return rpc_pair_from_dict(data, path)
    unknown = [str(k) for k in data if k not in KEYS]
    if unknown:
        raise RiverbedError(f"unknown key '{unknown[0]}' (pair file keys: {', '.join(KEYS)})", path)
    for key in ("P_left", "P_right"):
        if key not in data:
            raise RiverbedError(f"{key}: missing (a 3x4 projection matrix)", path)
    fields = {k: data[k] for k in ("P_left", "P_right", "width", "height") if data.get(k) is not None}
    for key in ("origin", "registration", "disparity"):
        if data.get(key) is not None:
            fields[key] = data[key]
    if data.get("crs") is not None:
        crs = data["crs"]
        if isinstance(crs, int) and not isinstance(crs, bool):
            crs = f"EPSG:{crs}"
        if isinstance(crs, str):
            _check_crs(crs, path)
        fields["crs"] = crs
    for key in ("left", "right"):
        value = data.get(key)
        if value is not None:
            if not isinstance(value, str) or not value:
                raise RiverbedError(f"{key}: expected a file name, got {value!r}", path)
            fields[key] = Path(os.path.normpath((path.parent / value).absolute()))
    try:
        return PairGeometry(**fields)
    except RiverbedError as e:
        if e.path is None:
            raise RiverbedError(str(e), path) from None
        raise


def load_registration(path):
    """A 4 x 4 LiDAR -> world transform from a file.

    Accepted: plain text with 16 numbers (4 rows of 4) or 12 (3 rows of 4, KITTI ``Tr_*`` style; ``0 0 0 1``
    appended), separated by spaces, commas or new lines; or YAML/JSON holding the matrix, bare or under the
    key ``registration`` (so a pair file can lend its registration).
    """
    path = Path(path)
    data, text = _parse(path, "registration file")
    if isinstance(data, dict):
        if "registration" not in data:
            raise RiverbedError("registration: missing (expected a 4x4 matrix)", path)
        data = data["registration"]
    if not isinstance(data, list):
        tokens = text.replace(",", " ").split()
        if len(tokens) not in (12, 16):
            raise RiverbedError(
                f"registration: expected 16 numbers (4x4) or 12 (3x4), got {len(tokens)} values", path)
        data = [tokens[i:i + 4] for i in range(0, len(tokens), 4)]
    if isinstance(data, list) and len(data) == 3:
        data = [*data, [0, 0, 0, 1]]
    try:
        reg = as_matrix(data, 4, 4, "registration")
        check_registration(reg)
    except RiverbedError as e:
        raise RiverbedError(str(e), path) from None
    return reg


def pair_to_dict(pair, folder=None):
    """A plain dict of a pair (lists of floats); image paths relative to ``folder`` when given."""
    out = {}
    for key in ("left", "right"):
        value = getattr(pair, key)
        if value is not None:
            out[key] = relative_path(value, folder) if folder is not None else str(value)
    if pair.width is not None:
        out["width"] = pair.width
    if pair.height is not None:
        out["height"] = pair.height
    out["P_left"] = pair.P_left.tolist()
    out["P_right"] = pair.P_right.tolist()
    if np.any(pair.origin != 0):
        out["origin"] = pair.origin.tolist()
    if pair.crs is not None:
        out["crs"] = pair.crs
    if np.any(pair.registration != np.eye(4)):
        out["registration"] = pair.registration.tolist()
    if pair.disparity is not None:
        out["disparity"] = [float(v) for v in pair.disparity]
    return out


def write_pairfile(path, pair, overwrite=False, comment=None):
    """Write ``pair`` as YAML (JSON for a ``.json`` suffix), atomically; paths relative to the file.

    Floats are written with ``repr`` precision, so :func:`load_pairfile` reads back the exact matrices.
    """
    path = Path(path)
    data = pair_to_dict(pair, path.parent)
    if path.suffix.lower() == ".json":
        text = json.dumps(data, indent=2) + "\n"
    else:
        head = "".join(f"# {line}\n" for line in (comment or "").splitlines())
        text = head + yaml.safe_dump(data, default_flow_style=None, sort_keys=False, width=200)
    with atomic_output(path, overwrite) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return path
