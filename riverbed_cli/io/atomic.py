"""Write outputs under a temporary name and rename them into place, so a failure never leaves half a file."""

import contextlib
import os
import uuid
from pathlib import Path

from ..errors import RiverbedError


def check_output(path, overwrite=False):
    """Raise :class:`RiverbedError` if ``path`` exists and ``overwrite`` is false, or its folder is missing."""
    path = Path(path)
    if path.exists() and not overwrite:
        raise RiverbedError("output exists; pass --overwrite to replace it", path)
    parent = path.parent if str(path.parent) else Path(".")
    if not parent.is_dir():
        raise RiverbedError(f"output folder {parent} does not exist", path)


def check_output_folder(outdir, names=(), overwrite=False):
    """Raise unless ``outdir`` is an existing folder or a new name inside an existing one, and (when it exists)
    unless each of the output ``names`` inside it may be written (:func:`check_output`); returns its parent."""
    outdir = Path(outdir)
    parent = outdir.parent if str(outdir.parent) else Path(".")
    if not parent.is_dir():
        raise RiverbedError(f"folder {parent} does not exist", outdir)
    if outdir.exists() and not outdir.is_dir():
        raise RiverbedError("exists and is not a folder", outdir)
    if outdir.is_dir():
        for name in names:
            check_output(outdir / name, overwrite)
    return parent


@contextlib.contextmanager
def atomic_output(path, overwrite=False):
    """Yield a temporary path beside ``path`` with the same suffix; rename it to ``path`` on success.

    On any exception the temporary file is removed and ``path`` is left as it was.
    """
    path = Path(path)
    check_output(path, overwrite)
    tmp = path.with_name(f".{path.stem}.{uuid.uuid4().hex[:8]}.tmp{path.suffix}")
    try:
        yield tmp
        os.replace(tmp, path)
    finally:
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()
