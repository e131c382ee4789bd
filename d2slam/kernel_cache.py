"""numba's on-disk cache of the compiled kernels, guarded: a damaged file is recompiled, never a crash.

numba keeps each ``cache=True`` kernel in an index (``.nbi``: which data file holds which signature) and data files
(``.nbc``: the pickled object code), beside the source or in ``$NUMBA_CACHE_DIR`` (``d2slam.run.warmup``). It trusts
them: a truncated index or data file ends the process with an ``UnpicklingError`` traceback, and a flipped bit in the
object code would run as machine code. :func:`install` (called by the modules that define kernels, before any is
loaded) changes how numba's ``IndexDataCacheFile`` writes and reads them:

* the index and data files it writes end with ``D2SLAM-SHA256`` and the sha256 of what precedes (numba's own reader
  ignores bytes after its pickles, so the files stay numba's);
* a data file is used only when that digest matches: otherwise the kernel is compiled again and the file rewritten,
  with one line on stderr when it was damaged (a whole pickle without the digest, written by numba outside d2slam,
  is recompiled without a word);
* an index whose digest does not match, or that cannot be read, counts as empty (the kernels are compiled again),
  with one line on stderr;
* a cache file that cannot be written (a full disk, a read-only folder) is one line on stderr: the kernel, compiled
  in memory, runs all the same.
"""

from __future__ import annotations

import hashlib
import io
import os
import pickle
from pathlib import Path

from d2slam.cachefiles import Damaged, report_damaged, say_once

TRAILER = b"D2SLAM-SHA256"
_INSTALLED = False


def _seal(blob: bytes) -> bytes:
    return blob + TRAILER + hashlib.sha256(blob).digest()


def _unseal(blob: bytes) -> bytes | None:
    """The pickle of a sealed data file; None when the file is a whole pickle without a seal (written by numba
    alone). :class:`~d2slam.cachefiles.Damaged` otherwise (a seal that does not match, a truncated file)."""
    n = len(TRAILER) + 32
    if len(blob) < n or blob[-n:-32] != TRAILER:
        try:
            pickle.loads(blob)
        except Exception as exc:  # noqa: BLE001 - not even a pickle: cut short
            raise Damaged(f"truncated or not a pickle ({type(exc).__name__})") from None
        return None
    body = blob[:-n]
    if hashlib.sha256(body).digest() != blob[-32:]:
        raise Damaged("its content does not match its sha256")
    return body


def install() -> None:
    """Guard numba's cache files in this process (idempotent)."""
    global _INSTALLED
    if _INSTALLED:
        return

    from numba.core import caching

    cls = caching.IndexDataCacheFile
    load_index = cls._load_index

    def _load_index(self):
        try:
            with open(self._index_path, "rb") as f:
                _unseal(f.read())  # Damaged when its seal does not match
            return load_index(self)
        except FileNotFoundError:
            return {}
        except Exception as exc:  # noqa: BLE001 - a damaged index: compile again
            report_damaged(self._index_path, "compiled-kernel index", exc, "compiling the kernels again")
            return {}

    def _save_index(self, overloads):
        blob = pickle.dumps(self._version, protocol=-1) + self._dump((self._source_stamp, overloads))
        with self._open_for_write(self._index_path) as f:
            f.write(_seal(blob))

    def _save_data(self, name, data):
        blob = _seal(self._dump(data))
        with self._open_for_write(self._data_path(name)) as f:
            f.write(blob)

    def load(self, key):
        data_name = self._load_index().get(key)
        if data_name is None:
            return None
        path = self._data_path(data_name)
        try:
            with open(path, "rb") as f:
                body = _unseal(f.read())
            return None if body is None else pickle.loads(body)
        except OSError:  # removed while the index still names it (numba's own behaviour)
            return None
        except (Damaged, Exception) as exc:  # noqa: BLE001 - truncated, flipped: compile again
            report_damaged(path, "compiled kernel", exc, "compiling it again")
            return None

    save = cls.save

    def save_(self, key, data):
        try:
            save(self, key, data)
        except OSError as exc:  # a full disk, a read-only folder: the kernel runs, compiled again next time
            say_once(f"kernel-cache|{self._cache_path}", f"d2slam: cannot write numba's kernel cache in "
                     f"{self._cache_path} ({exc.strerror or exc}): the kernels are compiled again next time")

    cls._load_index, cls._save_index, cls._save_data = _load_index, _save_index, _save_data
    cls.load, cls.save = load, save_
    _INSTALLED = True


def cache_files() -> list:
    """The cache files of d2slam's kernels: beside the package's sources (``__pycache__``) and under
    ``$NUMBA_CACHE_DIR`` when set."""
    package = Path(__file__).resolve().parent
    roots = [package] + ([Path(os.environ["NUMBA_CACHE_DIR"])] if os.environ.get("NUMBA_CACHE_DIR") else [])
    return sorted(p for root in roots if root.is_dir() for ext in ("nbi", "nbc") for p in root.rglob(f"*.{ext}"))


def check_file(path) -> str | None:
    """What is wrong with one of numba's cache files (None: nothing): an index that does not unpickle, a data file
    whose seal does not match or that is cut short."""
    try:
        with open(path, "rb") as f:
            blob = f.read()
        if str(path).endswith(".nbi"):
            f = io.BytesIO(blob)
            pickle.load(f)  # numba's version
            pickle.loads(f.read())  # the source stamp and the overloads
        else:
            _unseal(blob)
    except Damaged as exc:
        return str(exc)
    except Exception as exc:  # noqa: BLE001 - what numba would meet
        return f"{type(exc).__name__}: {exc}"
    return None


def preload(*modules) -> int:
    """Load now, from numba's disk cache, every kernel of ``modules`` that is cached for this machine and this code
    (each signature its index holds), which numba would otherwise load at the kernel's first call: a run calls this
    before its clock starts, so that its first frame does not count the loading (a few hundred milliseconds in all).
    It compiles nothing: a kernel without such a cached overload compiles at its first call, as before. Returns how
    many overloads were loaded."""
    from numba.core import dispatcher, registry

    codegen = registry.cpu_target.target_context.codegen()
    loaded = 0
    for module in modules:
        for kernel in vars(module).values():
            cache = getattr(kernel, "_cache", None) if isinstance(kernel, dispatcher.Dispatcher) else None
            if cache is None or not hasattr(cache, "_cache_file"):  # not cached on disk (numba's NullCache)
                continue
            for key in cache._cache_file._load_index():  # (signature, machine, code digests) -> data file
                sig = key[0]
                if sig not in kernel.overloads and cache._index_key(sig, codegen) == key:
                    kernel.compile(sig)  # found in the cache: loaded, not compiled
                    loaded += 1
    return loaded
