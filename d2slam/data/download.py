"""``d2slam download``: fetch, verify and extract an official TUM RGB-D archive.

Where: ``<base>/<group>/<archive>`` with ``<base>`` = ``--base-url``, else ``$D2SLAM_TUM_MIRROR``, else the
official ``https://cvg.cit.tum.de/rgbd/dataset`` followed by the older ``https://vision.in.tum.de/rgbd/dataset``
as a fallback mirror. The known sequences are in ``tum_sequences.json`` (package data).

Verification. No size or checksum of any TUM archive was known when the registry was written, so its ``size`` /
``sha256`` fields are null (a future release may fill them in; they are checked when present). What is checked:

1. the byte count against the server's Content-Length (or Content-Range total);
2. the sha256 and size of the archive against the record made the first time this machine downloaded it
   (``<cache>/tum_archives.json``, :func:`d2slam.paths.cache_dir`); the first download writes the record;
3. gzip integrity (the stream is read to its end, so the CRC and length trailer are checked) and tar structure;
4. the expected content: one top folder holding ``rgb.txt``, ``depth.txt``, ``groundtruth.txt``, ``rgb/`` and
   ``depth/`` files; every member a regular file or folder with a relative name inside that folder (no path
   traversal, no links); extraction also goes through ``tarfile``'s ``data`` filter;
5. the extracted folder opens with :class:`d2slam.data.tum.TumSequence`.

Resuming: bytes go to ``<archive>.part`` in the destination; a rerun asks for the rest with an HTTP Range
request and restarts cleanly if the server ignores it. An interrupted transfer is retried (resuming) a few times.
Without network it fails fast: DNS failure is immediate, connections time out after ``timeout`` seconds (10).
"""

from __future__ import annotations

import gzip
import json
import logging
import os
import re
import shutil
import tarfile
import tempfile
import time
import urllib.error
import urllib.request
import zlib
from dataclasses import dataclass
from http.client import HTTPException
from importlib import resources
from pathlib import Path, PurePosixPath

from tqdm import tqdm

from d2slam import __version__
from d2slam.cachefiles import sha256_file
from d2slam.data.config import DataConfig
from d2slam.data.tum import TumSequence
from d2slam.errors import D2SlamError
from d2slam.outputs import write_bytes
from d2slam.paths import cache_dir

#: Seconds to wait for a connection (and for each read) before calling the server unreachable / stalled
#: (``DataConfig.download_timeout``).
CONNECT_TIMEOUT = DataConfig().download_timeout
#: Automatic resumed retries of a transfer that breaks off after data started to flow.
TRANSFER_RETRIES = 3
CHUNK = 1 << 20
_log = logging.getLogger(__name__)
MIRROR_ENV = "D2SLAM_TUM_MIRROR"
RECORD_FILE = "tum_archives.json"
EXPECTED_FILES = ("rgb.txt", "depth.txt", "groundtruth.txt")
EXPECTED_DIRS = ("rgb", "depth")


@dataclass(frozen=True)
class SequenceInfo:
    name: str  # registry key, e.g. "fr3_walking_xyz"
    group: str  # "freiburg3"
    archive: str  # "rgbd_dataset_freiburg3_walking_xyz.tgz"
    dynamic: bool
    size: int | None
    sha256: str | None

    @property
    def folder(self) -> str:
        """The folder the archive extracts to."""
        return self.archive[: -len(".tgz")] if self.archive.endswith(".tgz") else self.archive


class _Unreachable(Exception):
    pass


class _HttpFailure(Exception):
    def __init__(self, code: int, reason: str):
        super().__init__(f"HTTP {code} {reason}")
        self.code = code


class _Interrupted(Exception):
    pass


# ------------------------------------------------------------------------------------------------------------------
# Registry
# ------------------------------------------------------------------------------------------------------------------
def _registry_data() -> dict:
    text = resources.files("d2slam.data").joinpath("tum_sequences.json").read_text()
    return json.loads(text)


def registry() -> dict[str, SequenceInfo]:
    """Known sequences by name (``fr3_walking_xyz``, ...)."""
    return {name: SequenceInfo(name=name, group=s["group"], archive=s["archive"], dynamic=bool(s["dynamic"]),
                               size=s.get("size"), sha256=s.get("sha256"))
            for name, s in _registry_data()["sequences"].items()}


def resolve(name: str) -> SequenceInfo:
    """Accepts ``fr3_walking_xyz``, ``fr3/walking_xyz``, ``freiburg3_walking_xyz``,
    ``rgbd_dataset_freiburg3_walking_xyz`` and the same with ``.tgz``."""
    key = name.strip().lower()
    key = re.sub(r"\.tgz$", "", key)
    key = re.sub(r"^rgbd_dataset_", "", key)
    key = re.sub(r"^freiburg([123])", r"fr\1", key).replace("/", "_")
    reg = registry()
    if key in reg:
        return reg[key]
    close = [n for n in reg if key and (key in n or n.split("_", 1)[1] == key)]
    hint = f" (did you mean {', '.join(close)}?)" if close else ""
    raise D2SlamError(f"unknown TUM sequence {name!r}{hint}; `d2slam download --list` shows the known ones")


def base_urls(base_url: str | None = None) -> list[str]:
    """``base_url`` if given, else ``$D2SLAM_TUM_MIRROR``, else the official server and its fallback mirror."""
    if base_url:
        return [base_url.rstrip("/")]
    env = os.environ.get(MIRROR_ENV)
    if env:
        return [env.rstrip("/")]
    data = _registry_data()
    return [data["base_url"].rstrip("/")] + [m.rstrip("/") for m in data.get("mirrors", [])]


def archive_urls(info: SequenceInfo, base_url: str | None = None) -> list[str]:
    return [f"{base}/{info.group}/{info.archive}" for base in base_urls(base_url)]


# ------------------------------------------------------------------------------------------------------------------
# Checksum records (cache)
# ------------------------------------------------------------------------------------------------------------------
def record_path() -> Path:
    return cache_dir() / RECORD_FILE


def load_records() -> dict:
    path = record_path()
    if not path.exists():
        return {}
    try:
        data = json.loads(path.read_text())
    except (json.JSONDecodeError, OSError) as exc:
        raise D2SlamError(f"cannot read the archive checksum records ({exc}); fix or delete the file",
                          path=path) from None
    if not isinstance(data, dict):
        raise D2SlamError("archive checksum records must be a JSON object; fix or delete the file", path=path)
    return data


def _save_record(archive: str, sha256: str, size: int, url: str) -> None:
    records = load_records()
    records[archive] = {"sha256": sha256, "size": size, "url": url,
                        "recorded": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())}

    write_bytes(record_path(), json.dumps(records, indent=1, sort_keys=True) + "\n")


# ------------------------------------------------------------------------------------------------------------------
# HTTP
# ------------------------------------------------------------------------------------------------------------------
def _parse_content_range(value: str | None) -> tuple[int, int | None] | None:
    m = re.fullmatch(r"\s*bytes\s+(\d+)-(\d+)/(\d+|\*)\s*", value or "")
    if not m:
        return None
    return int(m.group(1)), None if m.group(3) == "*" else int(m.group(3))


def fetch(url: str, part: Path, timeout: float = CONNECT_TIMEOUT, desc: str | None = None) -> int | None:
    """Download ``url`` into ``part``, resuming from its current size with a Range request. Returns the total
    size the server announced (None if it did not). Raises _Unreachable, _HttpFailure or _Interrupted."""
    for _attempt in range(2):  # second attempt only after discarding a .part the server cannot continue
        start = part.stat().st_size if part.exists() else 0
        headers = {"User-Agent": f"d2slam/{__version__}"}
        if start:
            headers["Range"] = f"bytes={start}-"
        try:
            resp = urllib.request.urlopen(urllib.request.Request(url, headers=headers), timeout=timeout)
        except urllib.error.HTTPError as exc:
            if exc.code == 416 and start:  # range not satisfiable: the .part is unusable, start again
                part.unlink()
                continue
            raise _HttpFailure(exc.code, str(exc.reason)) from None
        except urllib.error.URLError as exc:
            if isinstance(exc.reason, FileNotFoundError):  # a file:// mirror without the file: as an HTTP 404
                raise _HttpFailure(404, "Not Found (no such file)") from None
            raise _Unreachable(str(exc.reason)) from None
        except (OSError, HTTPException) as exc:  # timeouts, resets, refused connections, bad status lines
            raise _Unreachable(str(exc) or type(exc).__name__) from None
        with resp:
            status = resp.status
            length = resp.headers.get("Content-Length")
            length = int(length) if length and length.isdigit() else None
            if status == 206:
                rng = _parse_content_range(resp.headers.get("Content-Range"))
                if rng is None or rng[0] != start:  # a range we did not ask for: restart cleanly
                    part.unlink()
                    continue
                total = rng[1] if rng[1] is not None else (start + length if length is not None else None)
                mode = "ab"
            else:  # 200: the server ignored the Range header (or there was none): restart from byte 0
                start, mode = 0, "wb"
                total = length
            written = start
            try:
                with open(part, mode) as out, tqdm(total=total, initial=start, unit="B", unit_scale=True,
                                                   unit_divisor=1024, desc=desc or part.name, disable=None,
                                                   leave=False) as bar:
                    while True:
                        block = resp.read(CHUNK)
                        if not block:
                            break
                        out.write(block)
                        written += len(block)
                        bar.update(len(block))
            except (OSError, HTTPException) as exc:
                raise _Interrupted(f"{type(exc).__name__}: {exc}" if str(exc) else type(exc).__name__) from None
            if total is not None and written < total:
                raise _Interrupted(f"connection closed after {written} of {total} bytes")
            return total
    raise _Interrupted("the server could not continue the partial download")


# ------------------------------------------------------------------------------------------------------------------
# Archive verification and extraction
# ------------------------------------------------------------------------------------------------------------------
class _CountingReader:
    """File wrapper that advances a tqdm bar by the compressed bytes read."""

    def __init__(self, f, bar):
        self.f, self.bar = f, bar

    def read(self, n=-1):
        data = self.f.read(n)
        self.bar.update(len(data))
        return data

    def __getattr__(self, name):
        return getattr(self.f, name)


def _check_member(member: tarfile.TarInfo, archive: Path) -> tuple[str, ...]:
    name = member.name
    parts = PurePosixPath(name).parts
    if name.startswith(("/", "\\")) or re.match(r"^[A-Za-z]:", name) or ".." in parts or not parts:
        raise D2SlamError(f"unsafe member {name!r} (absolute path or '..'): refusing to extract", path=archive)
    if not (member.isfile() or member.isdir()):
        raise D2SlamError(f"member {name!r} is a link or special file: refusing to extract", path=archive)
    return tuple(p for p in parts if p != ".")


def verify_and_extract(archive: Path, dest: Path) -> Path:
    """Stream ``archive`` once: check every member, extract it into a temporary folder in ``dest``, read the gzip
    stream to its end (CRC check), then check the expected TUM files and move the top folder into ``dest``.
    Nothing is left in ``dest`` on failure. Returns the extracted folder."""
    tmp = Path(tempfile.mkdtemp(prefix=".d2slam-extract-", dir=dest))
    names: set[tuple[str, ...]] = set()
    try:
        with open(archive, "rb") as raw, tqdm(total=archive.stat().st_size, unit="B", unit_scale=True,
                                              unit_divisor=1024, desc=f"extract {archive.name}", disable=None,
                                              leave=False) as bar:
            try:
                with gzip.GzipFile(fileobj=_CountingReader(raw, bar), mode="rb") as gz:
                    with tarfile.open(fileobj=gz, mode="r|") as tar:
                        for member in tar:
                            parts = _check_member(member, archive)
                            names.add(parts)
                            tar.extract(member, path=tmp, filter="data", set_attrs=False)
                    while gz.read(CHUNK):  # drain to the gzip trailer: CRC-32 and length are verified here
                        pass
            except (gzip.BadGzipFile, EOFError, zlib.error, tarfile.TarError, OSError) as exc:
                raise D2SlamError(f"corrupt or truncated archive ({type(exc).__name__}: {exc})",
                                  path=archive) from None
        tops = {p[0] for p in names}
        if len(tops) != 1:
            raise D2SlamError(f"expected one top folder in the archive, found {len(tops)}: "
                              f"{', '.join(sorted(tops)[:5])}", path=archive)
        top = tops.pop()
        missing = [f for f in EXPECTED_FILES if (top, f) not in names or not (tmp / top / f).is_file()]
        missing += [d + "/" for d in EXPECTED_DIRS
                    if not any(len(p) == 3 and p[:2] == (top, d) and (tmp.joinpath(*p)).is_file() for p in names)]
        if missing:
            raise D2SlamError(f"not a TUM RGB-D archive: {top}/ lacks {', '.join(missing)}", path=archive)
        target = dest / top
        if target.exists():
            shutil.rmtree(target)
        os.replace(tmp / top, target)
        return target
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


# ------------------------------------------------------------------------------------------------------------------
# The command's work
# ------------------------------------------------------------------------------------------------------------------
def _manual_hint(info: SequenceInfo, urls: list[str], dest: Path) -> str:
    return (f"To download manually: fetch {urls[0]} on a machine with internet (browser, or `curl -C - -O "
            f"{urls[0]}`), copy it here and run `d2slam download {info.name} --to {dest} --archive "
            f"PATH/{info.archive}` (verifies, records the checksum and extracts). Or set ${MIRROR_ENV} / "
            f"--base-url to a server that mirrors the TUM layout.")


def download_urls(urls: list[str], part: Path, timeout: float = CONNECT_TIMEOUT, log=_log.info,
                  what: str = "file", hint: str = "") -> tuple[str, int]:
    """Download the first of ``urls`` that works into ``part`` (resuming, retried on interruption); returns
    (url used, bytes). Raises D2SlamError naming every failure, with ``hint`` (how to get the file otherwise)."""
    failures: list[str] = []
    unreachable = 0
    for url in urls:
        for attempt in range(TRANSFER_RETRIES + 1):
            try:
                total = fetch(url, part, timeout=timeout, desc=part.name[: -len(".part")] or part.name)
            except _Unreachable as exc:
                failures.append(f"{url}: unreachable ({exc})")
                unreachable += 1
                break
            except _HttpFailure as exc:
                failures.append(f"{url}: {exc}")
                break
            except _Interrupted as exc:
                if attempt < TRANSFER_RETRIES:
                    log(f"transfer interrupted ({exc}); resuming ({attempt + 1}/{TRANSFER_RETRIES})")
                    continue
                raise D2SlamError(f"download interrupted ({exc}); the partial file is kept, run the same command "
                                  "again to resume", path=part) from None
            size = part.stat().st_size
            if total is not None and size != total:
                raise D2SlamError(f"downloaded {size} bytes but the server announced {total}; run again to "
                                  "resume", path=part)
            return url, size
    if unreachable == len(urls):
        raise D2SlamError(f"cannot reach the server of the {what} (" + "; ".join(failures) + "). This machine may "
                          "be offline. " + hint)
    raise D2SlamError(f"download of the {what} failed: " + "; ".join(failures) + ". " + hint)


def _check_known(info: SequenceInfo, archive: Path, sha: str, size: int) -> dict | None:
    """Compare with the registry (when it has values) and this machine's record. Returns the record or None."""
    if info.size is not None and size != info.size:
        raise D2SlamError(f"size {size} differs from the registry's {info.size} for {info.archive}", path=archive)
    if info.sha256 is not None and sha != info.sha256:
        raise D2SlamError(f"sha256 {sha} differs from the registry's {info.sha256} for {info.archive}",
                          path=archive)
    rec = load_records().get(info.archive)
    if rec is not None and (rec.get("sha256") != sha or rec.get("size") != size):
        raise D2SlamError(
            f"checksum mismatch: this archive has sha256 {sha} ({size} bytes) but the first download recorded on "
            f"{rec.get('recorded', '?')} from {rec.get('url', '?')} had sha256 {rec.get('sha256')} "
            f"({rec.get('size')} bytes) in {record_path()}. The archive is kept for inspection; if the server's "
            f"file legitimately changed, delete the {info.archive!r} entry of that record and run again.",
            path=archive)
    return rec


def download_sequence(name: str, dest: str | Path, base_url: str | None = None, archive: str | Path | None = None,
                      keep_archive: bool = False, force: bool = False, timeout: float = CONNECT_TIMEOUT,
                      log=_log.info) -> Path:
    """Download (or take ``archive``), verify and extract sequence ``name`` into ``dest``; returns the sequence
    folder (``dest/rgbd_dataset_freiburgN_NAME``). See the module docstring for every check. When nothing could be
    downloaded, the folders it created for ``dest`` are removed again."""
    info = resolve(name)
    dest = Path(dest).expanduser()
    created = [d for d in (dest, *dest.parents) if not d.exists()]  # removed again if nothing arrives
    try:
        dest.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise D2SlamError(f"cannot create the destination folder: {exc.strerror or exc}", path=dest) from None
    try:
        return _download_into(info, dest, base_url, archive, keep_archive, force, timeout, log)
    except BaseException:
        part = dest / (info.archive + ".part")
        if part.is_file() and part.stat().st_size == 0:
            part.unlink()
        for d in created:  # deepest first; a folder holding anything (a resumable .part) stays
            try:
                d.rmdir()
            except OSError:
                break
        raise


def _download_into(info: SequenceInfo, dest: Path, base_url, archive, keep_archive: bool, force: bool,
                   timeout: float, log) -> Path:
    """:func:`download_sequence` once ``dest`` exists."""

    target = dest / info.folder
    if target.exists() and not force:
        if all((target / f).is_file() for f in EXPECTED_FILES[:2]):
            seq = TumSequence(target)
            log(f"{target} already present ({len(seq)} frames); --force to download again")
            return target
        raise D2SlamError("exists but is not a complete TUM sequence; remove it or use --force", path=target)

    urls = archive_urls(info, base_url)
    user_archive = archive is not None
    if user_archive:
        path = Path(archive).expanduser()
        if not path.is_file():
            raise D2SlamError("archive not found", path=path)
        source = str(path.resolve())
    else:
        path = dest / info.archive
        part = dest / (info.archive + ".part")
        if path.is_file():
            source = "(previously downloaded)"
            log(f"using {path} already downloaded")
        else:
            source, _ = download_urls(urls, part, timeout, log, what=f"TUM archive {info.archive}",
                                      hint=_manual_hint(info, urls, dest))
            os.replace(part, path)

    size = path.stat().st_size
    sha = sha256_file(path)
    try:
        rec = _check_known(info, path, sha, size)
        folder = verify_and_extract(path, dest)
    except D2SlamError as exc:
        if not user_archive and "checksum mismatch" not in str(exc):
            bad = path.with_name(path.name + ".corrupt")
            os.replace(path, bad)
            raise D2SlamError(f"{exc} (moved aside to {bad.name}; run again to download afresh)") from None
        raise
    if rec is None:
        _save_record(info.archive, sha, size, source)
        log(f"recorded sha256 {sha} ({size} bytes) of {info.archive} in {record_path()}")
    else:
        log(f"sha256 matches the record of {rec.get('recorded', '?')}")
    if folder.name != info.folder:
        log(f"note: the archive's folder is {folder.name!r}, not {info.folder!r}")
    seq = TumSequence(folder)
    if not user_archive and not keep_archive:
        path.unlink()
    log(f"{info.name}: {len(seq)} RGB-D frames, camera {seq.camera.name}, in {folder}")
    return folder


def format_list() -> str:
    reg = registry()
    base = base_urls()
    rows = [f"{'name':<44} {'dynamic':<8} archive"]
    rows += [f"{n:<44} {'yes' if s.dynamic else 'no':<8} {base[0]}/{s.group}/{s.archive}" for n, s in reg.items()]
    rows.append(f"({len(reg)} sequences; sizes and checksums are recorded on first download in "
                f"{cache_dir()}/{RECORD_FILE})")
    return "\n".join(rows)


__all__ = ["SequenceInfo", "registry", "resolve", "base_urls", "archive_urls", "download_sequence", "fetch",
           "download_urls",
           "verify_and_extract", "sha256_file", "load_records", "record_path", "format_list", "CONNECT_TIMEOUT"]
