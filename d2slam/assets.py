"""The files a checkout needs but git does not hold: the YOLOv8n-seg models, five real TUM fr3 frames and the first
120 frames of the real TUM RGB-D recording fr1/rpy (the "head").

Lookup (every consumer goes through :func:`asset_path` and :func:`real_head`): the shared folder (``$D2SLAM_SHARED``,
default ``../shared`` beside the checkout) when it holds the file, else the cache (``$D2SLAM_CACHE/assets``, same
layout). Nothing here downloads unless :func:`fetch_assets` (``d2slam assets fetch``) or :func:`fetch_real_full`
(``d2slam assets fetch --full-real``) is called.

``d2slam assets fetch`` downloads the files of :data:`DOWNLOADS` from pinned commits of public GitHub repositories
(``$D2SLAM_ASSETS_MIRROR`` replaces ``https://raw.githubusercontent.com/``), checks their sha256, and derives the two
float models of :data:`DERIVED` from the int8 one with :func:`d2slam.dequantize.dequantize` (the
result has the same sha256 as the shared files). Files already found (shared folder or cache) are not fetched again.

Real data (:func:`real_pins`, ``d2slam/data/real_assets.json``: URLs and checksums, never the data): TUM fr1/rpy as
kept in a public GitHub copy of the official archive, at a pinned commit. The head (:func:`fetch_real_head`, part of
``d2slam assets fetch``): the whole sequence's ``rgb.txt``, ``depth.txt`` and ``groundtruth.txt`` (sha256 checked),
cut to the first 120 images (:func:`cut_head`; the cut lists' sha256 checked), and those images (each one's sha256
checked), into ``$D2SLAM_CACHE/assets/real/rgbd_dataset_freiburg1_rpy_head120``. The whole sequence
(:func:`fetch_real_full`, for development): its lists (sha256 checked) and every image they name (723 RGB, 722 depth;
no per-image checksum is known, so each must decode as a 640x480 8-bit colour or 16-bit depth PNG) into
``$D2SLAM_CACHE/real/rgbd_dataset_freiburg1_rpy`` (:func:`real_full`). Both are written into a temporary folder
beside their place and renamed into it when complete; an interrupted fetch leaves that folder with the files it had
checked, and the next fetch takes it over and resumes.
"""

from __future__ import annotations

import glob
import hashlib
import json
import logging
import os
from contextlib import contextmanager
from dataclasses import dataclass
from functools import lru_cache
from importlib import resources
from pathlib import Path
from typing import Callable, Iterator

from d2slam.data.download import CONNECT_TIMEOUT, download_urls, sha256_file
from d2slam.data.intrinsics import camera_from_folder
from d2slam.data.tum import TumSequence, read_depth, read_file_list, read_rgb
from d2slam.dequantize import dequantize_file
from d2slam.errors import D2SlamError
from d2slam.outputs import remove_stale_temps, replace_dir, stale_temp, temp_name
from d2slam.paths import cache_dir, shared_dir
from d2slam.progress import progress

_log = logging.getLogger(__name__)
MIRROR_ENV = "D2SLAM_ASSETS_MIRROR"
UPSTREAM = "https://raw.githubusercontent.com/"
_DASHCAM = "udaypartha/dashcam/7a2d55819df7f17222042203db878a3d23d3aaa5/"
_DYNASLAM = "BertaBescos/DynaSLAM/a0be7394e74a7b7a91e0a5aa31b29543cd0aa144/imgs/"
INT8_MODEL = "models/yolov8n-seg_int8.onnx"
TUM_FRAMES_DIR = "images/tum_fr3"


@dataclass(frozen=True)
class Download:
    path: str  # relative to the shared folder / the assets cache
    url_path: str  # relative to UPSTREAM (or the mirror)
    sha256: str
    licence: str


@dataclass(frozen=True)
class Derived:
    path: str
    height: int  # model input, pixels
    width: int
    sha256: str  # of the converter's output (the same bytes as the shared file)


#: Downloaded files (pinned commits; same bytes as the shared folder's).
DOWNLOADS = (
    Download(INT8_MODEL, _DASHCAM + "yolov8n-seg_int8.onnx",
             "a892891617cbadd34d860f66a866393a8d4c487c49f1474e9b6d9e578332e56a", "AGPL-3.0 (Ultralytics weights)"),
    *(Download(f"{TUM_FRAMES_DIR}/fr3_walking_frame_{n}.png", _DYNASLAM + f"id{n}rgbInput.png", sha, "CC BY 4.0 (TUM)")
      for n, sha in (("0193", "af2a68a7a2d69126738dde4674ed9395ed20db3d8dfd61d8ead2b60b120271a2"),
                     ("0216", "9f24d5241f56830ea24afde804a96359be404522c0d676fdcd4fffba5c0ca0e8"),
                     ("0241", "e394d26909f0a8500c3a4cd918acc374f6f5ac4a0d056b84e8f3bfc92e93cc78"),
                     ("0427", "8345e188868c87f0735394d419570e665d6d6ce93512db1346a654e2a2037008"),
                     ("0546", "c1fbba1bb221e3f44eb6a0941bcf232a8c8ea1178ad7cc3af42d261128a7e9ec"))),
)
#: Float models derived locally from ``INT8_MODEL`` (input fixed to height x width).
DERIVED = (
    Derived("models/yolov8n-seg_deq_384x512.onnx", 384, 512,
            "37b2e7e7d3e00f273d4490fdb3c167e579b6279d8b2c43c330693db05d7cf51d"),
    Derived("models/yolov8n-seg_deq_256x320.onnx", 256, 320,
            "0e1c0fe92741cc4554e13bb9fba2d37717ede3dc6fe4c6c93db3d6ab0bbdc85d"),
)
ALL_ASSETS = tuple(a.path for a in DOWNLOADS) + tuple(d.path for d in DERIVED)
HOW_TO_FETCH = (f"run `d2slam assets fetch` (or `make test` / `make demo`, which run it): it downloads the model, "
                f"the five TUM frames and the first 120 frames of TUM fr1/rpy from pinned GitHub commits ({UPSTREAM}, "
                f"or ${MIRROR_ENV}=URL of a mirror with the same layout), checks their sha256 and derives the float "
                f"models into the cache; or set $D2SLAM_SHARED to a folder holding models/, images/tum_fr3/ and real/")


def assets_cache() -> Path:
    """Where fetched and derived assets live: ``$D2SLAM_CACHE/assets`` (the shared folder's layout)."""
    return cache_dir("assets")


def find(rel: str) -> Path | None:
    """The file ``rel`` (e.g. ``models/yolov8n-seg_int8.onnx``) in the shared folder, else in the cache, else None."""
    for root in (shared_dir(), assets_cache()):
        path = root / rel
        if path.is_file():
            return path
    return None


def asset_path(rel: str) -> Path:
    """:func:`find`, or a ``D2SlamError`` saying how to fetch the file."""
    path = find(rel)
    if path is None:
        raise D2SlamError(f"{rel} is in neither {shared_dir()} nor {assets_cache()}; {HOW_TO_FETCH}")
    return path


def tum_frames() -> list[Path]:
    """The five real TUM fr3 walking frames (640x480 RGB PNGs), in frame order."""
    return [asset_path(a.path) for a in DOWNLOADS if a.path.startswith(TUM_FRAMES_DIR + "/")]


def missing() -> list[str]:
    """Assets found neither in the shared folder nor in the cache."""
    return [rel for rel in ALL_ASSETS if find(rel) is None]


def _base_url() -> str:
    """``$D2SLAM_ASSETS_MIRROR`` when set, else ``https://raw.githubusercontent.com``, without its trailing slash."""
    return (os.environ.get(MIRROR_ENV) or UPSTREAM).rstrip("/")


def upstream_url(asset: Download) -> str:
    """The asset's URL: ``$D2SLAM_ASSETS_MIRROR`` (when set) in place of ``https://raw.githubusercontent.com/``."""
    return _base_url() + "/" + asset.url_path


def _install(tmp: Path, dest: Path, sha256: str, source: str) -> None:
    """Check ``tmp``'s sha256 and move it to ``dest``; a mismatch deletes it and raises."""
    digest = sha256_file(tmp)
    if digest != sha256:
        tmp.unlink()
        raise D2SlamError(f"sha256 {digest} of {source} differs from the pinned {sha256}; the file was deleted "
                          "(a wrong mirror, or a changed upstream file)", path=dest)
    os.replace(tmp, dest)


def fetch_assets(timeout: float | None = None, echo=_log.info) -> list[Path]:
    """Download every missing file of :data:`DOWNLOADS` into the cache, verify it, derive the missing float
    models of :data:`DERIVED`, and fetch the real head when it is missing (:func:`fetch_real_head`). Returns the
    files and folders written (empty when everything was found)."""
    written: list[Path] = []
    root = assets_cache()
    for asset in DOWNLOADS:
        if find(asset.path) is not None:
            continue
        dest = root / asset.path
        dest.parent.mkdir(parents=True, exist_ok=True)
        part = dest.with_name(dest.name + ".part")
        url = upstream_url(asset)
        echo(f"fetching {url}")
        download_urls([url], part, timeout or CONNECT_TIMEOUT, echo, what=asset.path,
                      hint=f"Fetch {url} by hand into {dest} (sha256 {asset.sha256}), or set ${MIRROR_ENV} to a "
                      "reachable mirror, or $D2SLAM_SHARED to a folder holding the files.")
        _install(part, dest, asset.sha256, url)
        written.append(dest)
    for model in DERIVED:
        if find(model.path) is not None:
            continue

        dest = root / model.path
        dest.parent.mkdir(parents=True, exist_ok=True)
        echo(f"deriving {model.path} ({model.height}x{model.width} float) from {INT8_MODEL}")
        tmp = dequantize_file(asset_path(INT8_MODEL), dest.with_name(dest.name + ".part"), model.height,
                              model.width)
        _install(tmp, dest, model.sha256, f"the float {model.height}x{model.width} model derived from {INT8_MODEL}")
        written.append(dest)
    head = fetch_real_head(timeout, echo)
    if head is not None:
        written.append(head)
    return written


# ------------------------------------------------------------------------------------------------------------------
# Real RGB-D data: TUM fr1/rpy from a public GitHub copy of the official archive
# ------------------------------------------------------------------------------------------------------------------
# The real data's folder: the head's beside models/ and images/ (shared folder, assets cache), the whole sequence's
# in the cache.
REAL_DIR = "real"
LISTS = ("rgb.txt", "depth.txt", "groundtruth.txt")
_WHOLE_LISTS = ".whole"  # where a fetch of the head keeps the whole sequence's lists until it has cut them


@lru_cache(maxsize=1)
def real_pins() -> dict:
    """The pinned copy of the real recording (repository, commit, folder), the sha256 of its lists and the head's
    definition and checksums: ``d2slam/data/real_assets.json``."""
    return json.loads(resources.files("d2slam.data").joinpath("real_assets.json").read_text())


def real_url(rel: str) -> str:
    """The raw URL of ``rel`` (``rgb.txt``, ``rgb/<t>.png``) in the pinned copy (``$D2SLAM_ASSETS_MIRROR`` in place
    of ``https://raw.githubusercontent.com/``)."""
    pins = real_pins()
    return f"{_base_url()}/{pins['repository']}/{pins['commit']}/{pins['folder']}/{rel}"


def real_head_rel() -> str:
    """The head's folder relative to the shared folder and the assets cache."""
    return f"{REAL_DIR}/{real_pins()['head']['folder']}"


def _sha256_is(path: Path, sha256: str) -> bool:
    return path.is_file() and sha256_file(path) == sha256


def _is_head(folder: Path) -> bool:
    """``folder`` holds the head: the three cut lists with their pinned sha256 and every image at its pinned size (an
    image's sha256 is checked when it is fetched)."""
    head = real_pins()["head"]
    if not all(_sha256_is(folder / name, sha) for name, sha in head["lists"].items()):
        return False
    for rel, (_sha, size) in head["files"].items():
        try:
            if (folder / rel).stat().st_size != size:
                return False
        except OSError:
            return False
    return True


def find_real_head() -> Path | None:
    """The folder of the first 120 frames of TUM fr1/rpy (TUM layout) in the shared folder, else in the cache, else
    None."""
    for root in (shared_dir(), assets_cache()):
        folder = root / real_head_rel()
        if _is_head(folder):
            return folder
    return None


def real_head() -> Path:
    """:func:`find_real_head`, or a ``D2SlamError`` saying how to fetch it: what tests, notebooks and benchmarks
    read the real recording's head from."""
    folder = find_real_head()
    if folder is None:
        raise D2SlamError(f"the first {real_pins()['head']['frames']} frames of TUM fr1/rpy ({real_head_rel()}) are "
                          f"in neither {shared_dir()} nor {assets_cache()}; {HOW_TO_FETCH}")
    return folder


def real_full_dir() -> Path:
    """Where ``d2slam assets fetch --full-real`` puts the whole sequence: ``$D2SLAM_CACHE/real/<sequence>``."""
    return cache_dir(REAL_DIR) / real_pins()["sequence"]


def _listed(folder: Path) -> list[str]:
    """The images ``folder``'s rgb.txt and depth.txt name (relative paths), in list order."""
    return [name for lst in LISTS[:2] for name in read_file_list(folder / lst)[1]]


def _is_full(folder: Path) -> bool:
    """``folder`` holds the whole sequence: its lists with their pinned sha256 and every image they name."""
    if not all(_sha256_is(folder / name, sha) for name, sha in real_pins()["lists"].items()):
        return False
    return all((folder / rel).is_file() for rel in _listed(folder))


def real_full() -> Path | None:
    """The whole TUM fr1/rpy sequence (TUM layout) in the shared folder (``real/<sequence>``), else in the cache
    (:func:`real_full_dir`), else None (``d2slam assets fetch --full-real`` gets it)."""
    for folder in (shared_dir() / REAL_DIR / real_pins()["sequence"], real_full_dir()):
        if _is_full(folder):
            return folder
    return None


def _split_list(data: bytes) -> tuple[list[bytes], list[bytes]]:
    """A TUM list's leading comment lines and its entries (blank lines dropped), each line with its line end."""
    lines = data.splitlines(keepends=True)
    n = 0
    while n < len(lines) and lines[n].lstrip().startswith(b"#"):
        n += 1
    return lines[:n], [line for line in lines[n:] if line.strip() and not line.lstrip().startswith(b"#")]


def _stamp(line: bytes) -> float:
    return float(line.split()[0])


def cut_head(lists: dict[str, bytes], frames: int, margin_s: float) -> dict[str, bytes]:
    """The lists of the first ``frames`` images of a TUM sequence from the whole sequence's (``{name: bytes}`` of
    :data:`LISTS`): rgb.txt and depth.txt keep their comment lines and first ``frames`` entries; groundtruth.txt its
    comment lines and the poses within ``margin_s`` seconds of the span of those images' timestamps."""
    out, span = {}, []
    for name in LISTS[:2]:
        header, entries = _split_list(lists[name])
        kept = entries[:frames]
        out[name] = b"".join(header + kept)
        span += [_stamp(kept[0]), _stamp(kept[-1])] if kept else []
    header, poses = _split_list(lists[LISTS[2]])
    lo, hi = min(span) - margin_s, max(span) + margin_s
    out[LISTS[2]] = b"".join(header + [p for p in poses if lo <= _stamp(p) <= hi])
    return out


@contextmanager
def _resumable_dir(dest: Path) -> Iterator[Path]:
    """A folder to fetch ``dest`` into: this process's temporary folder beside it (:func:`d2slam.outputs.temp_name`),
    taking over the one an interrupted fetch left (its process gone) with the files it had checked. Renamed to
    ``dest`` when the block ends; kept when it raises, for the next fetch to resume."""
    dest.parent.mkdir(parents=True, exist_ok=True)
    work = temp_name(dest)
    pattern = glob.escape(dest.name) + ".tmp-*"
    if not work.exists():
        for old in sorted(dest.parent.glob(pattern)):
            if old.is_dir() and stale_temp(old.name):
                os.replace(old, work)
                break
    remove_stale_temps(dest.parent, pattern)
    work.mkdir(exist_ok=True)
    yield work
    replace_dir(work, dest)


def _fetch_checked(rel: str, dest: Path, check: Callable[[Path], None], timeout: float | None, echo) -> None:
    """Download ``rel`` of the pinned copy into ``dest`` through ``dest.part`` (resumed when a part is there), run
    ``check(part)`` (raises ``D2SlamError``; the part is then deleted) and rename it to ``dest``. Nothing is done
    when ``dest`` is there (it was checked before it got its name)."""
    if dest.is_file():
        return
    dest.parent.mkdir(parents=True, exist_ok=True)
    part = dest.with_name(dest.name + ".part")
    url = real_url(rel)
    download_urls([url], part, timeout or CONNECT_TIMEOUT, echo, what=f"file {rel} of TUM fr1/rpy",
                  hint=f"Set ${MIRROR_ENV} to a reachable mirror of {UPSTREAM} (same paths), or $D2SLAM_SHARED to "
                  f"a folder holding {real_head_rel()}/; the files checked so far are kept in {dest.parent} and the "
                  "next fetch resumes.")
    try:
        check(part)
    except D2SlamError:
        part.unlink(missing_ok=True)
        raise
    os.replace(part, dest)


def _sha256_check(sha256: str, rel: str) -> Callable[[Path], None]:
    def check(path: Path) -> None:
        digest = sha256_file(path)
        if digest != sha256:
            raise D2SlamError(f"sha256 {digest} of {real_url(rel)} differs from the pinned {sha256}; the file was "
                              "deleted (a wrong mirror, or a changed upstream file)", path=path)

    return check


def _fetch_lists(work: Path, shas: dict[str, str], timeout, echo) -> None:
    """The whole sequence's lists into ``work``, each checked against its pinned sha256."""
    for name in LISTS:
        _fetch_checked(name, work / name, _sha256_check(shas[name], name), timeout, echo)


def fetch_real_head(timeout: float | None = None, echo=_log.info) -> Path | None:
    """Fetch the first 120 frames of TUM fr1/rpy into the assets cache unless :func:`find_real_head` finds them: the
    whole sequence's lists (sha256 checked), cut by :func:`cut_head` (the cut lists' sha256 checked), and the
    images they name (each one's sha256 checked). Returns the folder written, or None when nothing was fetched."""
    if find_real_head() is not None:
        return None
    pins = real_pins()
    head = pins["head"]
    dest = assets_cache() / real_head_rel()
    megabytes = sum(size for _sha, size in head["files"].values()) / 1e6
    echo(f"fetching the first {head['frames']} frames of TUM fr1/rpy ({len(head['files'])} images, "
         f"{megabytes:.0f} MB) from {real_url('')} into {dest}")
    with _resumable_dir(dest) as work:
        lists = work / _WHOLE_LISTS
        _fetch_lists(lists, pins["lists"], timeout, echo)
        cut = cut_head({name: (lists / name).read_bytes() for name in LISTS}, head["frames"],
                       head["groundtruth_margin_s"])
        for name, data in cut.items():
            digest = hashlib.sha256(data).hexdigest()
            if digest != head["lists"][name]:
                raise D2SlamError(f"the head's {name} cut from the whole sequence's has sha256 {digest}, not the "
                                  f"pinned {head['lists'][name]} (d2slam/data/real_assets.json)", path=lists / name)
            (work / name).write_bytes(data)
        named = _listed(work)
        if sorted(named) != sorted(head["files"]):
            raise D2SlamError("the head's lists name other images than d2slam/data/real_assets.json pins", path=work)
        for rel in progress(named, desc="TUM fr1/rpy head", unit="image"):
            _fetch_checked(rel, work / rel, _sha256_check(head["files"][rel][0], rel), timeout, echo)
        for name in LISTS:
            (lists / name).unlink()
        lists.rmdir()
    return dest


def _decode_check(rel: str, shape: tuple[int, int], depth_factor: float) -> Callable[[Path], None]:
    """A check that the image ``rel`` (``rgb/...`` or ``depth/...``) decodes as the sequence's 8-bit colour or 16-bit
    depth PNG of ``shape`` (height, width)."""

    def check(path: Path) -> None:
        try:
            if rel.startswith("depth/"):
                read_depth(path, depth_factor, shape=shape)
            else:
                read_rgb(path, shape=shape)
        except D2SlamError as exc:
            raise D2SlamError(f"{real_url(rel)} arrived but is not a usable image ({exc}); it was deleted") from None

    return check


def fetch_real_full(timeout: float | None = None, echo=_log.info) -> Path | None:
    """Fetch the whole TUM fr1/rpy sequence into :func:`real_full_dir` unless :func:`real_full` finds it: its lists
    (sha256 checked) and every image they name (no per-image checksum is known: each must decode as the camera's
    640x480 colour or 16-bit depth PNG). Returns the folder written, or None when nothing was fetched."""
    if real_full() is not None:
        return None
    dest = real_full_dir()
    camera = camera_from_folder(dest)
    echo(f"fetching the whole TUM fr1/rpy sequence from {real_url('')} into {dest}")
    with _resumable_dir(dest) as work:
        _fetch_lists(work, real_pins()["lists"], timeout, echo)
        named = _listed(work)
        echo(f"{len(named)} images ({sum(r.startswith('rgb/') for r in named)} RGB, "
             f"{sum(r.startswith('depth/') for r in named)} depth) to fetch and decode")
        for rel in progress(named, desc="TUM fr1/rpy", unit="image"):
            _fetch_checked(rel, work / rel, _decode_check(rel, (camera.height, camera.width), camera.depth_factor),
                           timeout, echo)
        TumSequence(work, camera=camera)  # the lists associate and every image they name is there
    return dest
