"""The one exception type riverbed raises for bad input.

A :class:`RiverbedError` carries a one-line, user-facing message that names the file (when there is one) and the
problem. The CLI turns it into ``riverbed: error: <message>`` on stderr and exit code 1, never a traceback.
"""


class RiverbedError(ValueError):
    """Bad input or an impossible request, with a message meant for the user."""

    def __init__(self, message, path=None):
        self.path = None if path is None else str(path)
        super().__init__(f"{self.path}: {message}" if self.path else message)


#: longest message the CLI prints (characters, after escaping); longer ones lose their middle
MAX_MESSAGE = 500


def one_line(text, limit=MAX_MESSAGE):
    """``text`` as one printable line of at most ``limit`` characters: control characters (ESC, CR, LF, ...) escaped
    as ``\\x1b``, ``\\r``, ``\\n``, so a hostile file's text cannot drive the terminal or forge lines; a longer text
    keeps its start and end around `` ... ``."""
    out = []
    for ch in str(text):
        o = ord(ch)
        if o < 32 or 127 <= o < 160 or ch in "\u2028\u2029":
            out.append({"\n": "\\n", "\r": "\\r", "\t": "\\t"}.get(ch) or (f"\\x{o:02x}" if o < 256 else f"\\u{o:04x}"))
        else:
            out.append(ch)
    line = "".join(out)
    if len(line) > limit:
        keep = limit - 5
        line = line[:keep - keep // 3] + " ... " + line[len(line) - keep // 3:]
    return line
