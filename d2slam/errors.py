"""The one exception type users see. Every message names the file (and line, where there is one)."""

from __future__ import annotations

from pathlib import Path


class D2SlamError(Exception):
    """A clear, user-facing error: bad input, missing file, unreachable server, ...

    The CLI prints ``d2slam: error: <message>`` and exits with status 2 instead of a traceback.
    """

    def __init__(self, message: str, path: str | Path | None = None, line: int | None = None):
        self.path = None if path is None else Path(path)
        self.line = line
        where = ""
        if path is not None:
            where = f"{path}:{line}: " if line is not None else f"{path}: "
        super().__init__(where + message)
