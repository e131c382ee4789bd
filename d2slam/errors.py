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


def read_text(path: str | Path, what: str) -> str:
    """The text of the input file ``path``, or a one-line :class:`D2SlamError` naming it (``what``: e.g. "camera
    settings") when it is missing or cannot be read as text."""
    path = Path(path)
    if not path.is_file():
        raise D2SlamError(f"{what} file not found", path=path)
    try:
        return path.read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise D2SlamError(f"cannot read {what} as text ({exc})", path=path) from None
