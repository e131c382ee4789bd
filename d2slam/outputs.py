"""Output paths checked before a run starts: a clear one-line ``D2SlamError`` instead of a traceback after the work.

:func:`check_output_file`: the file's folder exists, is a folder and accepts a new file; the path is not a folder.
:func:`check_output_dir`: a folder the command creates: not an existing file, and its nearest existing ancestor
accepts a new entry. Writability is probed by creating (and removing) a temporary file, which also catches a
read-only file system and permissions that ``os.access`` misjudges.

Temporary files and folders (written, then renamed into place, so that nobody reads half an output and an
interrupted command leaves no half-made one) are named ``<name>.tmp-<pid>@<host>[...]`` (:func:`temp_name`): the
process that owns one can be told from its name, and :func:`remove_stale_temps` removes only those whose process
is gone (on this host), never the work in progress of another process sharing the folder (the cache).
:func:`staged_file` and :func:`staged_dir` write a file or a whole folder that way; a write that fails (disk full,
file too large) is a one-line ``D2SlamError`` naming the file, and the previous file, if any, is left as it was.

Outputs never land on inputs (:func:`check_outputs`): an output path that is an input file (itself, through a
symbolic link or as a hard link), lies inside an input folder, inside any sequence folder (one holding ``rgb.txt``),
inside the folders of the cache that d2slam manages (:func:`d2slam.paths.managed_cache_dirs`) or inside the shared
folder, or two outputs of one command that are the same file, are refused before any work, in one line naming both
paths.

:class:`file_lock` is the one lock of the project (an exclusive ``flock`` on a lock file, released when the process
ends however it ends): the vocabulary build, the cached sequences, the mask cache's writes and segmentation, and a
study's output folder take it.
"""

from __future__ import annotations

import fcntl
import os
import re
import shutil
import socket
import sys
import tempfile
from contextlib import contextmanager
from pathlib import Path
from typing import Iterable, Iterator

from d2slam.errors import D2SlamError
from d2slam.paths import managed_cache_dirs, shared_dir


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


def write_error(exc: OSError, path: str | Path) -> D2SlamError:
    """The one-line error of a write that failed (``No space left on device``, ``File too large``, ...); its
    ``reason`` is the system's."""
    err = D2SlamError(f"cannot write ({exc.strerror or exc}); nothing was written", path=path)
    err.reason = exc.strerror or str(exc)
    return err


@contextmanager
def staged_file(path: str | Path, suffix: str = "") -> Iterator[Path]:
    """A temporary path beside ``path`` (:func:`temp_name`; ``suffix`` e.g. ``.npz`` for writers that add one) to
    write into; renamed to ``path`` when the block ends normally, removed when it raises. A write that fails with an
    ``OSError`` (disk full, file too large, folder gone) becomes :func:`write_error`; ``path`` keeps what it held."""
    path = Path(path)
    tmp = temp_name(path, suffix)
    try:
        yield tmp
        os.replace(tmp, path)
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        raise write_error(exc, path) from None
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def write_bytes(path: str | Path, data: bytes | str) -> Path:
    """Write ``data`` (text is UTF-8) to ``path`` whole or not at all (:func:`staged_file`)."""
    with staged_file(path) as tmp:
        with open(tmp, "wb") as f:
            f.write(data.encode() if isinstance(data, str) else data)
    return Path(path)


def save_figure(fig, path: str | Path, **kwargs) -> Path:
    """``fig.savefig`` whole or not at all (:func:`staged_file`; the format from ``path``'s suffix)."""
    path = Path(path)
    with staged_file(path, path.suffix) as tmp:
        fig.savefig(tmp, format=path.suffix.lstrip(".") or None, **kwargs)
    return path


# ---------------------------------------------------------------------------------------------- one lock
class file_lock:
    """An exclusive ``flock`` on the file ``path`` (created, never removed: removing it would let a third process
    lock a new file while the second holds the old one) for the duration of a ``with`` block. When another process
    holds it: with ``refuse`` (a message) a ``D2SlamError`` saying so; otherwise ``waiting`` (a message) is printed
    once on stderr and the lock is waited for. The lock dies with its process, however it ends (kill -9 too)."""

    def __init__(self, path: str | Path, waiting: str | None = None, refuse: str | None = None):
        self.path, self.waiting, self.refuse = Path(path), waiting, refuse
        self.f = None

    def __enter__(self) -> "file_lock":
        try:
            self.f = open(self.path, "a")
        except OSError as exc:
            raise D2SlamError(f"cannot create a lock file ({exc.strerror or exc}); the folder must be writable "
                              "(for the cache: set $D2SLAM_CACHE to a writable folder)", path=self.path) from None
        try:
            fcntl.flock(self.f, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            if self.refuse is not None:
                self.f.close()
                raise D2SlamError(self.refuse, path=self.path) from None
            if self.waiting:
                print(self.waiting, file=sys.stderr, flush=True)
            fcntl.flock(self.f, fcntl.LOCK_EX)
        return self

    def __exit__(self, *exc) -> bool:
        self.f.close()  # releases the lock
        return False


# ---------------------------------------------------------------------------------------------- outputs vs inputs
def is_sequence_dir(path: str | Path) -> bool:
    """A TUM-layout sequence folder (``rgb.txt``; a d2slam synthetic sequence also has ``scene.json``)."""
    path = Path(path)
    return (path / "rgb.txt").is_file() or (path / "scene.json").is_file()


def _real(path: Path) -> Path:
    """``path`` made absolute with every symbolic link resolved (the final one too, dangling or not)."""
    return Path(os.path.realpath(Path(path).expanduser()))


def _same_file(a: Path, b: Path) -> bool:
    try:
        return os.path.samefile(a, b)  # hard links too
    except OSError:
        return False


def _hard_link_into(path: Path, folder: Path) -> Path | None:
    """The file of ``folder`` that ``path`` is a hard link to (only looked for when ``path`` has several links)."""
    try:
        st = path.stat()
    except OSError:
        return None
    if st.st_nlink < 2 or not path.is_file():
        return None
    for p in folder.rglob("*"):
        try:
            other = p.stat()
        except OSError:
            continue
        if (other.st_ino, other.st_dev) == (st.st_ino, st.st_dev):
            return p
    return None


def _inside(path: Path, folder: Path) -> bool:
    return path == folder or folder in path.parents


def _shown(given: Path, real: Path) -> str:
    """How a path is named in a message: as given, plus where it really is when a link leads elsewhere."""
    absolute = Path(os.path.abspath(given.expanduser()))
    return f"{given}" if absolute == real else f"{given} (= {real})"


def _sequence_holding(real: Path, include_self: bool, own: Path | None = None) -> Path | None:
    """The sequence folder ``real`` lies in (or is, with ``include_self``), ``own`` left out, else None."""
    for folder in ([real] if include_self else []) + list(real.parents):
        if folder != own and folder.is_dir() and is_sequence_dir(folder):
            return folder
    return None


def check_outputs(outputs: Iterable[tuple[str, str | Path | None]],
                  inputs: Iterable[tuple[str, str | Path | None]] = (), folders: bool = False,
                  own_sequence: str | Path | None = None) -> None:
    """Refuse, before any work, outputs that would overwrite what a command reads or what d2slam keeps.

    ``outputs``: ``(option, path)`` pairs (``("--out", "traj.txt")``; None skipped); ``folders``: they are folders
    the command writes into (``study --out``, ``segment --overlay``). ``inputs``: ``(what, path)`` pairs of the
    command's input files and folders (a sequence folder, ``--config``, the ground truth, ...). Refused, with one
    line naming both paths: an output that is an input file (the same path, through a link, or a hard link to it);
    an output inside an input folder, inside any sequence folder (:func:`is_sequence_dir`; an output folder that is
    one too, except ``own_sequence``: the sequence ``d2slam synth`` replaces), inside a folder of the cache that
    d2slam manages or inside the shared folder; two outputs that are the same file."""

    outs = [(opt, Path(p).expanduser()) for opt, p in outputs if p is not None]
    ins = [(what, Path(p).expanduser()) for what, p in inputs if p is not None]
    own = _real(Path(own_sequence)) if own_sequence is not None else None
    seen: list[tuple[str, Path, Path]] = []
    for opt, given in outs:
        real = _real(given)
        for other_opt, other_given, other_real in seen:
            if other_real == real or _same_file(other_real, real):
                raise D2SlamError(f"{opt} and {other_opt} are the same file ({_shown(other_given, other_real)}, "
                                  f"{_shown(given, real)}): each output needs its own path",)
        seen.append((opt, given, real))
        for what, inp in ins:
            inp_real = _real(inp)
            if inp_real.is_dir():
                if _inside(real, inp_real):
                    raise D2SlamError(f"{opt} {_shown(given, real)} lies inside the input {what} "
                                      f"{_shown(inp, inp_real)}: d2slam never writes into its inputs; give another "
                                      "path",)
            elif real == inp_real or _same_file(real, inp_real):
                raise D2SlamError(f"{opt} {_shown(given, real)} is the input {what} {_shown(inp, inp_real)}: d2slam "
                                  "never overwrites its inputs; give another path",)
            twin = _hard_link_into(real, inp_real) if inp_real.is_dir() else None
            if twin is not None:
                raise D2SlamError(f"{opt} {_shown(given, real)} is a hard link to {twin} of the input {what} "
                                  f"{inp_real}: d2slam never overwrites its inputs; give another path",)
        seq = _sequence_holding(real, include_self=folders, own=own)
        if seq is not None:
            raise D2SlamError(f"{opt} {_shown(given, real)} lies inside the sequence folder {seq} (it holds "
                              f"{'scene.json' if (seq / 'scene.json').is_file() else 'rgb.txt'}): d2slam never "
                              "writes into a sequence; give another path",)
        for folder, what in [(shared_dir(), "the shared folder of read-only assets")] + managed_cache_dirs():
            folder = _real(folder)
            if _inside(real, folder):
                raise D2SlamError(f"{opt} {_shown(given, real)} lies inside {what} {folder}: that folder is "
                                  "d2slam's own; give another path",)
