"""Input paths: one place for the existence checks every reader makes."""

from pathlib import Path

from ..errors import RiverbedError


def require_file(path):
    """``Path(path)`` if it names a regular file; otherwise a one-line :class:`RiverbedError` naming it."""
    path = Path(path)
    if not path.exists():
        raise RiverbedError("file not found", path)
    if not path.is_file():
        raise RiverbedError("not a file", path)
    return path
