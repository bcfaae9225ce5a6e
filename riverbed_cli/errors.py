"""The one exception type riverbed raises for bad input.

A :class:`RiverbedError` carries a one-line, user-facing message that names the file (when there is one) and the
problem. The CLI turns it into ``riverbed: error: <message>`` on stderr and exit code 1, never a traceback.
"""


class RiverbedError(ValueError):
    """Bad input or an impossible request, with a message meant for the user."""

    def __init__(self, message, path=None):
        self.path = None if path is None else str(path)
        super().__init__(f"{self.path}: {message}" if self.path else message)
