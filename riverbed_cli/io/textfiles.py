"""Small text inputs from strangers (pair files, orientations, manifests): size-checked, UTF-8, safe YAML."""


import yaml

from ..errors import RiverbedError
from .paths import require_file


def read_text(path, what, max_bytes):
    """The UTF-8 text of ``path``; one-line errors for a missing, non-regular, oversized or binary file."""
    path = require_file(path)
    size = path.stat().st_size
    if size > max_bytes:
        raise RiverbedError(f"too large for a {what} ({size} bytes, limit {max_bytes})", path)
    try:
        return path.read_bytes().decode("utf-8")
    except UnicodeDecodeError:
        raise RiverbedError(f"not a {what} (not UTF-8 text)", path) from None


def parse_yaml(text, path):
    """``yaml.safe_load`` with a one-line error naming the line and column of a syntax error."""
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark else ""
        problem = getattr(e, "problem", None) or type(e).__name__
        raise RiverbedError(f"invalid YAML{where}: {problem}", path) from None
