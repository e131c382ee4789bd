"""Output paths checked before a run starts: a clear one-line ``D2SlamError`` instead of a traceback after the work.

:func:`check_output_file`: the file's folder exists, is a folder and accepts a new file; the path is not a folder.
:func:`check_output_dir`: a folder the command creates: not an existing file, and its nearest existing ancestor
accepts a new entry. Writability is probed by creating (and removing) a temporary file, which also catches a
read-only file system and permissions that ``os.access`` misjudges.

Temporary files and folders (written, then renamed into place, so that nobody reads half an output and an
interrupted command leaves no half-made one) are named ``<name>.tmp-<pid>@<host>[...]`` (:func:`temp_name`): the
process that owns one can be told from its name, and :func:`remove_stale_temps` removes only those whose process
is gone (on this host), never the work in progress of another process sharing the folder (the cache).
:func:`staged_file` and :func:`staged_dir` write a file or a whole folder that way.
"""

from __future__ import annotations

import os
import re
import shutil
import socket
import tempfile
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

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


# ``.tmp-<pid>``, optionally ``@<host>``, then the end of the name or a separator (``.npz``, ``-<random>``, ``.old``)
_TEMP = re.compile(r"\.tmp-(\d+)(?:@(\w+))?(?=$|[.-])")


def _host() -> str:
    return re.sub(r"\W", "_", socket.gethostname())[:40] or "localhost"


def temp_tag() -> str:
    """``.tmp-<pid>@<host>``: what this process's temporary names carry."""
    return f".tmp-{os.getpid()}@{_host()}"


def temp_name(path: str | Path, suffix: str = "") -> Path:
    """A temporary path beside ``path`` owned by this process: ``<name>.tmp-<pid>@<host><suffix>``."""
    path = Path(path)
    return path.with_name(f"{path.name}{temp_tag()}{suffix}")


def _alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's process
        return True
    except OverflowError:  # not a process id at all
        return False
    return True


def stale_temp(name: str) -> bool:
    """``name`` is a temporary name (:func:`temp_name`) whose process is gone: a process id of this host (or of no
    recorded host) that is not running. Another host's temporaries are never stale here."""
    m = _TEMP.search(name)
    if m is None:
        return False
    if m.group(2) is not None and m.group(2) != _host():
        return False
    return not _alive(int(m.group(1)))


def remove_stale_temps(folder: str | Path, pattern: str = "*.tmp-*") -> list[Path]:
    """Remove the entries of ``folder`` matching ``pattern`` (a glob, e.g. ``*/*/.tmp-*``) left by processes that
    are gone (:func:`stale_temp`): files and folders. Returns what was removed."""
    folder = Path(folder)
    removed = []
    if not folder.is_dir():
        return removed
    for entry in sorted(folder.glob(pattern)):
        if not stale_temp(entry.name):
            continue
        if entry.is_dir() and not entry.is_symlink():
            shutil.rmtree(entry, ignore_errors=True)
        else:
            entry.unlink(missing_ok=True)
        removed.append(entry)
    return removed


def replace_dir(src: str | Path, dst: str | Path) -> Path:
    """Move the folder ``src`` to ``dst``; an existing ``dst`` is moved aside first and removed afterwards (put back
    if the move fails)."""
    src, dst = Path(src), Path(dst)
    old = None
    if dst.exists():
        old = temp_name(dst, ".old")
        shutil.rmtree(old, ignore_errors=True)
        os.replace(dst, old)
    try:
        os.replace(src, dst)
    except BaseException:
        if old is not None:
            os.replace(old, dst)
        raise
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)
    return dst


@contextmanager
def staged_dir(path: str | Path) -> Iterator[Path]:
    """A new empty folder beside ``path`` (:func:`temp_name`) to write into; when the block ends normally it replaces
    ``path`` (:func:`replace_dir`), when it raises (``KeyboardInterrupt`` too) it is removed: ``path`` is either
    left as it was or complete."""
    path = Path(path)
    tmp = temp_name(path)
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir(parents=True)
    try:
        yield tmp
        replace_dir(tmp, path)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


@contextmanager
def staged_file(path: str | Path, suffix: str = "") -> Iterator[Path]:
    """A temporary path beside ``path`` (:func:`temp_name`; ``suffix`` e.g. ``.npz`` for writers that add one) to
    write into; renamed to ``path`` when the block ends normally, removed when it raises."""
    path = Path(path)
    tmp = temp_name(path, suffix)
    try:
        yield tmp
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
