"""The cache's files are checked when read; a damaged one is remade, with one line saying so.

Everything in the cache (``d2slam.paths.cache_dir``) is derived and can be made again, so a file that cannot be
trusted (truncated by a full disk or a crash of another tool, bit-flipped, edited by hand) is never used and never
crashes a command: it is reported on stderr in one line (:func:`report_damaged`) and remade by whoever needed it.
How each kind is checked:

* ``.npz`` files (masks, extracted features, the engine's bag-of-words vocabulary, a study's run arrays):
  :func:`load_npz` reads every array in full, so that ``zipfile`` checks each member's CRC-32; any error on the way
  (``BadZipFile``, a zlib error, a malformed ``.npy`` header, a missing array) means damaged. A flipped bit goes
  unnoticed only where zip does not look (a date field of the directory), which changes no array;
* folders (cached sequences, the vocabulary's training frames): written with a manifest of their files (size,
  modification time, sha256: :func:`folder_manifest`); :func:`folder_problems` compares sizes and modification times
  on every use and hashes again the files whose time changed (``full=True``: every file, ``d2slam cache check
  --full``);
* JSON records whose numbers matter (a study's run records): they carry the sha256 of their own content
  (:func:`sealed`, :func:`unsealed`);
* the vocabulary text: its manifest holds its sha256 (``d2slam.baselines.vocab``);
* numba's compiled kernels: :mod:`d2slam.kernel_cache`.
"""

from __future__ import annotations

import hashlib
import json
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from d2slam.errors import D2SlamError
from d2slam.ranges import Checked, within


@dataclass(frozen=True)
class CacheConfig(Checked):
    """How far the caches' cheap checks trust a file's recorded size and time (a section of
    ``d2slam.config.CliConfig``); nothing here changes a run's numbers."""

    # The caches' cheap checks (the mask cache's image digest, a cached folder's manifest) trust a file's size and
    # modification time only when it was last modified at least this long before they were recorded: a change made
    # within a file system's timestamp resolution (FAT: 2 s; ext4, tmpfs: 1 ns) could keep the recorded time.
    cache_mtime_window_s: float = within(2.0, 0.0, 3600.0)


CACHE = CacheConfig()

_REPORTED: set[str] = set()


class Damaged(D2SlamError):
    """A cache file that cannot be trusted; the message says why. Its readers catch it and remake the file; one that
    escaped would still be one line on the command line, not a traceback."""


def say_once(key: str, line: str) -> None:
    """``line`` on stderr, once per ``key`` and process."""
    if key not in _REPORTED:
        _REPORTED.add(key)
        print(line, file=sys.stderr, flush=True)


def _reason(reason: object) -> str:
    if isinstance(reason, Damaged):
        reason = str(reason)
    elif isinstance(reason, BaseException):
        reason = f"{type(reason).__name__}: {reason}" if str(reason) else type(reason).__name__
    return " ".join(str(reason).split())[:200]


def report_damaged(path: str | Path, what: str, reason: object, action: str) -> None:
    """One line on stderr: ``d2slam: damaged WHAT PATH (REASON): ACTION`` (once per file and process)."""
    say_once(f"{path}|{action}", f"d2slam: damaged {what} {path} ({_reason(reason)}): {action}")


def sha256_file(path: str | Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def load_npz(path: str | Path, names: tuple[str, ...] | None = None) -> dict:
    """Every array of the ``.npz`` at ``path`` (or the arrays ``names``, which must all be there), read in full;
    :class:`Damaged` when it cannot be, whatever the reason (a missing file is ``FileNotFoundError``)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(path)
    try:
        with open(path, "rb") as fh, np.load(fh, allow_pickle=False) as z:  # closed whatever np.load makes of it
            missing = [n for n in names or () if n not in z.files]
            if missing:
                raise Damaged(f"arrays {missing} missing")
            return {n: z[n] for n in (names or z.files)}
    except Damaged:
        raise
    except Exception as exc:  # noqa: BLE001 - zip, zlib, npy header, I/O: all mean the file cannot be used
        raise Damaged(f"{type(exc).__name__}: {exc}" if str(exc) else type(exc).__name__) from None


# ---------------------------------------------------------------------------------------------- folders
def folder_manifest(folder: str | Path, skip: tuple[str, ...] = ()) -> dict:
    """``{relative path: [size, mtime_ns, sha256]}`` of every file under ``folder`` (names in ``skip`` left out:
    the marker that holds the manifest)."""
    folder = Path(folder)
    out = {}
    for p in sorted(folder.rglob("*")):
        rel = p.relative_to(folder).as_posix()
        if p.is_file() and rel not in skip:
            st = p.stat()
            out[rel] = [st.st_size, st.st_mtime_ns, sha256_file(p)]
    return out


def folder_problems(folder: str | Path, manifest: dict, full: bool = False, limit: int = 3) -> list[str]:
    """What differs between ``folder`` and its ``manifest`` (:func:`folder_manifest`): files missing, of another
    size, or whose content changed. Sizes and modification times are compared for every file; a file is hashed
    again when its time differs from the recorded one (or for every file with ``full``). At most ``limit``
    problems are listed (the first ones, by name)."""
    folder = Path(folder)
    problems = []
    for rel, (size, mtime_ns, sha) in sorted(manifest.items()):
        p = folder / rel
        try:
            st = p.stat()
        except OSError:
            problems.append(f"{rel} missing")
        else:
            if st.st_size != size:
                problems.append(f"{rel} has {st.st_size} bytes, {size} recorded")
            elif (full or st.st_mtime_ns != mtime_ns) and sha256_file(p) != sha:
                problems.append(f"{rel} changed (sha256)")
        if len(problems) >= limit:
            break
    return problems


# ---------------------------------------------------------------------------------------------- sealed records
def _canonical(record: dict) -> bytes:
    return json.dumps(record, sort_keys=True, separators=(",", ":"), default=str).encode()


def sealed(record: dict) -> dict:
    """``record`` with ``"sha256"``: the digest of the rest of it (canonical JSON)."""
    body = {k: v for k, v in record.items() if k != "sha256"}
    return {**body, "sha256": hashlib.sha256(_canonical(body)).hexdigest()}


def unsealed(record: dict) -> dict:
    """``record`` without its seal when the seal matches; :class:`Damaged` when it does not. A record without a seal
    (written before records had one) is returned as it is."""
    if "sha256" not in record:
        return record
    body = {k: v for k, v in record.items() if k != "sha256"}
    if hashlib.sha256(_canonical(body)).hexdigest() != record["sha256"]:
        raise Damaged("its content does not match its sha256")
    return body


def read_json(path: str | Path) -> dict:
    """A JSON object from ``path``; :class:`Damaged` when it is not one (``FileNotFoundError`` when missing)."""
    path = Path(path)
    try:
        data = json.loads(path.read_bytes())
    except FileNotFoundError:
        raise
    except (OSError, ValueError) as exc:
        raise Damaged(f"{type(exc).__name__}: {exc}") from None
    if not isinstance(data, dict):
        raise Damaged("not a JSON object")
    return data


def mtime_settled(mtime_ns: int, window_s: float, now_ns: int | None = None) -> bool:
    """Whether a file modified at ``mtime_ns`` was last modified at least ``window_s`` before ``now_ns`` (default:
    now): a later change within the file system's timestamp resolution then shows as a new time."""
    return (time.time_ns() if now_ns is None else now_ns) - mtime_ns >= window_s * 1e9
