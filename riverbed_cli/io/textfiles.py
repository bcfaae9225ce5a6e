"""Small text inputs from strangers (pair files, orientations, manifests, expectations): size-checked, UTF-8, and
parsed as JSON or safe YAML within bounds on nesting and on YAML's alias expansion.

Bounds, so that a hostile file is refused in one line, quickly and in little memory:

- size: at most ``max_bytes`` are ever read (a file that grows while it is read, or a device, cannot push more);
- nesting: at most :data:`MAX_DEPTH` levels of lists and mappings (the JSON decoder and PyYAML's composer
  recurse, so a 10,000-deep file would end in a RecursionError);
- YAML aliases: the document expanded (every alias replaced by its anchor's node, as anything that walks the
  result sees it) has at most :data:`MAX_YAML_NODES` nodes, counted from the parser's event stream before any
  object is built: a "billion laughs" file of a few hundred bytes stands for 10**9 nodes. Aliases themselves are
  allowed (``riverbed block split-rpc`` shares one ROI mapping through an anchor).
"""

import json
import re

import yaml

from ..errors import RiverbedError
from .paths import require_file

#: Deepest nesting of lists and mappings accepted in a JSON or YAML file.
MAX_DEPTH = 64
#: Most nodes (scalars, lists, mappings) a YAML document may hold with its aliases expanded.
MAX_YAML_NODES = 1_000_000

# A JSON string (what may hide brackets), or one bracket.
_JSON_TOKENS = re.compile(r'"(?:[^"\\]|\\.)*"|[\[\]{}]', re.DOTALL)


def read_text(path, what, max_bytes):
    """The UTF-8 text of ``path``; one-line errors for a missing, non-regular, oversized or binary file.

    A leading UTF-8 byte-order mark is kept (callers that accept one strip it).
    """
    path = require_file(path)
    try:
        with open(path, "rb") as f:
            data = f.read(max_bytes + 1)
    except OSError as e:
        raise RiverbedError(f"cannot read {what} ({e.strerror or e})", path) from None
    if len(data) > max_bytes:
        size = max(path.stat().st_size, len(data))
        raise RiverbedError(f"too large for a {what} ({size} bytes, limit {max_bytes})", path)
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError:
        raise RiverbedError(f"not a {what} (not UTF-8 text)", path) from None


def parse_json(text, path, max_depth=MAX_DEPTH):
    """``json.loads`` with one-line errors: syntax errors by line and column, nesting deeper than ``max_depth``
    refused before decoding, and numbers Python refuses (an integer of more than 4300 digits)."""
    depth = 0
    for m in _JSON_TOKENS.finditer(text):
        c = m.group()
        if c in "[{":
            depth += 1
            if depth > max_depth:
                line = text.count("\n", 0, m.start()) + 1
                raise RiverbedError(f"invalid JSON at line {line}: nested more than {max_depth} levels deep", path)
        elif c in "]}":
            depth -= 1
    try:
        return json.loads(text)
    except json.JSONDecodeError as e:
        raise RiverbedError(f"invalid JSON at line {e.lineno}, column {e.colno}: {e.msg}", path) from None
    except (ValueError, RecursionError) as e:
        raise RiverbedError(f"invalid JSON: {str(e).splitlines()[0][:200]}", path) from None


def check_yaml_bounds(text, path, max_depth=MAX_DEPTH, max_nodes=MAX_YAML_NODES):
    """Refuse YAML nested deeper than ``max_depth`` or holding more than ``max_nodes`` nodes once its aliases are
    expanded, from the parser's events (no recursion, no objects built, memory of one number per anchor).

    Syntax errors are left to the loader, which reports them with their line and column.
    """
    sizes = {}  # anchor -> expanded nodes of its node (an anchor may be redefined: the latest counts)
    open_nodes = []  # (anchor, expanded nodes before it) of each collection being read
    total = 0
    try:
        # PyYAML's own parser, as safe_load uses: a state machine, no recursion (libyaml's scanner stops at 1000
        # levels with an error, after which safe_load's composer would still recurse)
        for event in yaml.parse(text, Loader=yaml.SafeLoader):
            if isinstance(event, yaml.AliasEvent):
                total += sizes.get(event.anchor, 1)
            elif isinstance(event, yaml.ScalarEvent):
                total += 1
                if event.anchor is not None:
                    sizes[event.anchor] = 1
            elif isinstance(event, yaml.CollectionStartEvent):
                total += 1
                open_nodes.append((event.anchor, total - 1))
                if len(open_nodes) > max_depth:
                    raise RiverbedError(_where(event) + f"nested more than {max_depth} levels deep", path)
                continue
            elif isinstance(event, yaml.CollectionEndEvent):
                anchor, before = open_nodes.pop()
                if anchor is not None:
                    sizes[anchor] = total - before
            else:
                continue
            if total > max_nodes:
                raise RiverbedError(_where(event) + f"aliases expand to more than {max_nodes} nodes", path)
    except yaml.YAMLError:
        return  # the loader reports it


def _where(event):
    mark = event.start_mark
    return f"invalid YAML at line {mark.line + 1}, column {mark.column + 1}: " if mark else "invalid YAML: "


def parse_yaml(text, path):
    """``yaml.safe_load`` within :func:`check_yaml_bounds`, with a one-line error naming the line and column of a
    syntax error."""
    check_yaml_bounds(text, path)
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark else ""
        problem = getattr(e, "problem", None) or type(e).__name__
        raise RiverbedError(f"invalid YAML{where}: {problem}", path) from None
    except (ValueError, RecursionError) as e:  # e.g. an integer of more than 4300 digits
        raise RiverbedError(f"invalid YAML: {str(e).splitlines()[0][:200]}", path) from None


def load_text_data(path, what, max_bytes, fmt=None):
    """A JSON or YAML file read and parsed within the bounds above: the one reader of structured user files.

    Parameters
    ----------
    path : path-like
    what : str
        What the file is, for messages ("pair file", "block manifest").
    max_bytes : int
        Larger files are refused without reading past this.
    fmt : {"json", "yaml", None}
        None: JSON for a ``.json`` name or text starting with ``{``, YAML otherwise.

    Returns
    -------
    data : object
        The parsed document.
    text : str
        The file's text.
    """
    text = read_text(path, what, max_bytes)
    if fmt is None:
        fmt = "json" if str(path).lower().endswith(".json") or text.lstrip().startswith("{") else "yaml"
    return (parse_json(text, path) if fmt == "json" else parse_yaml(text, path)), text
