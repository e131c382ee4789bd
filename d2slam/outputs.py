"""Output paths checked before a run starts: a clear one-line ``D2SlamError`` instead of a traceback after the work.

:func:`check_output_file`: the file's folder exists, is a folder and accepts a new file; the path is not a folder.
:func:`check_output_dir`: a folder the command creates: not an existing file, and its nearest existing ancestor
accepts a new entry. Writability is probed by creating (and removing) a temporary file, which also catches a
read-only file system and permissions that ``os.access`` misjudges.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

from d2slam.errors import D2SlamError


def _probe(folder: Path, what: str) -> None:
    try:
        fd, name = tempfile.mkstemp(prefix=".d2slam-write-check-", dir=folder)
    except OSError as exc:
        raise D2SlamError(f"{what}: cannot write into the folder ({exc.strerror or exc})", path=folder) from None
    os.close(fd)
    os.unlink(name)


def check_output_file(path: str | Path, what: str = "output") -> Path:
    """``path`` can be written (``what`` names the option in the message, e.g. ``--metrics-json``)."""
    path = Path(path).expanduser()
    if path.is_dir():
        raise D2SlamError(f"{what}: is a folder, expected a file path", path=path)
    folder = path.parent
    if not folder.exists():
        raise D2SlamError(f"{what}: the folder does not exist (create it first)", path=folder)
    if not folder.is_dir():
        raise D2SlamError(f"{what}: {folder.name!r} is not a folder", path=folder)
    _probe(folder, what)
    return path


def check_output_dir(path: str | Path, what: str = "output folder") -> Path:
    """``path`` is a folder, or can be created as one."""
    path = Path(path).expanduser()
    if path.exists() and not path.is_dir():
        raise D2SlamError(f"{what}: exists and is not a folder", path=path)
    existing = path
    while not existing.exists():
        existing = existing.parent
    if not existing.is_dir():
        raise D2SlamError(f"{what}: {existing} is not a folder", path=path)
    _probe(existing, what)
    return path
