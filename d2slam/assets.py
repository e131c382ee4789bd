"""The files a checkout needs but git does not hold: the YOLOv8n-seg models and five real TUM fr3 frames.

Lookup (every consumer goes through :func:`asset_path`): the shared folder (``$D2SLAM_SHARED``, default ``../shared``
beside the checkout) when it holds the file, else the cache (``$D2SLAM_CACHE/assets``, same layout). Nothing here
downloads unless :func:`fetch_assets` (``d2slam assets fetch``) is called.

``d2slam assets fetch`` downloads the files of :data:`DOWNLOADS` from pinned commits of public GitHub repositories
(``$D2SLAM_ASSETS_MIRROR`` replaces ``https://raw.githubusercontent.com/``), checks their sha256, and derives the two
float models of :data:`DERIVED` from the int8 one with :func:`d2slam.dequantize.dequantize` (the
result has the same sha256 as the shared files). Files already found (shared folder or cache) are not fetched again.
"""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass
from pathlib import Path

from d2slam.errors import D2SlamError
from d2slam.paths import cache_dir, shared_dir

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
HOW_TO_FETCH = (f"run `d2slam assets fetch` (or `make test` / `make demo`, which run it): it downloads the model and "
                f"the five TUM frames from pinned GitHub commits ({UPSTREAM}, or ${MIRROR_ENV}=URL of a mirror with "
                f"the same layout), checks their sha256 and derives the float models into the cache; or set "
                f"$D2SLAM_SHARED to a folder holding models/ and images/tum_fr3/")


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


def upstream_url(asset: Download) -> str:
    """The asset's URL: ``$D2SLAM_ASSETS_MIRROR`` (when set) in place of ``https://raw.githubusercontent.com/``."""
    base = os.environ.get(MIRROR_ENV) or UPSTREAM
    return base.rstrip("/") + "/" + asset.url_path


def _install(tmp: Path, dest: Path, sha256: str, source: str) -> None:
    """Check ``tmp``'s sha256 and move it to ``dest``; a mismatch deletes it and raises."""
    from d2slam.data.download import sha256_file

    digest = sha256_file(tmp)
    if digest != sha256:
        tmp.unlink()
        raise D2SlamError(f"sha256 {digest} of {source} differs from the pinned {sha256}; the file was deleted "
                          "(a wrong mirror, or a changed upstream file)", path=dest)
    os.replace(tmp, dest)


def fetch_assets(timeout: float | None = None, echo=_log.info) -> list[Path]:
    """Download every missing file of :data:`DOWNLOADS` into the cache, verify it, and derive the missing float
    models of :data:`DERIVED`. Returns the files written (empty when everything was found)."""
    from d2slam.data.download import CONNECT_TIMEOUT, download_urls

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
        from d2slam.dequantize import dequantize_file

        dest = root / model.path
        dest.parent.mkdir(parents=True, exist_ok=True)
        echo(f"deriving {model.path} ({model.height}x{model.width} float) from {INT8_MODEL}")
        tmp = dequantize_file(asset_path(INT8_MODEL), dest.with_name(dest.name + ".part"), model.height,
                              model.width)
        _install(tmp, dest, model.sha256, f"the float {model.height}x{model.width} model derived from {INT8_MODEL}")
        written.append(dest)
    return written
