"""Per-frame mask cache, so that runs and ablations never segment a frame twice.

Layout: ``cache_dir("masks", <sequence key>, <segmenter key>)/<timestamp>.npz`` with

* sequence key = ``<folder name>-<sha256(resolved root path + sha256(rgb.txt))[:16]>`` (the timestamps when there is no
  ``rgb.txt``): a moved or edited sequence gets a new key;
* segmenter key = ``<kind>-<sha256(identity)[:16]>`` where ``identity()`` holds the model's sha256, the decoder
  version and every config value that changes masks (score threshold, NMS IoU, mask threshold, dilation,
  max persons; not the thread count): another model or config never reads stale masks;
* one compressed ``.npz`` per frame, named by the RGB timestamp (``%.6f``): ``bits`` (``np.packbits`` of the
  (k, H, W) masks), ``shape``, ``scores`` (k,), ``boxes`` (k, 4), ``timestamp``.

Files are written atomically (a temporary file named after the writing process, :mod:`d2slam.outputs`, then a
rename). A corrupt or inconsistent file is reported with a warning naming it, recomputed and overwritten (documented
recovery). ``meta.json`` beside the files records the keys.
"""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
import warnings
import zipfile
from pathlib import Path

import numpy as np

from d2slam.errors import D2SlamError
from d2slam.outputs import temp_tag
from d2slam.paths import cache_dir
from d2slam.segmentation.base import PersonInstance


def _digest(blob: bytes) -> str:
    return hashlib.sha256(blob).hexdigest()


def sequence_key(sequence) -> str:
    """Identity of a sequence: its name, resolved root and the content of ``rgb.txt`` (or its timestamps)."""
    root = Path(sequence.root).resolve()
    rgb_txt = root / "rgb.txt"
    content = _digest(rgb_txt.read_bytes()) if rgb_txt.is_file() else _digest(
        np.ascontiguousarray(np.asarray(sequence.timestamps, dtype=np.float64)).tobytes())
    name = "".join(c if c.isalnum() or c in "-_." else "_" for c in root.name)
    return f"{name[:60]}-{_digest(f'{root}|{content}'.encode())[:16]}"


def segmenter_key(segmenter) -> str:
    ident = segmenter.identity()
    return f"{ident.get('kind', segmenter.name)}-{_digest(json.dumps(ident, sort_keys=True).encode())[:16]}"


def timestamp_stem(timestamp: float) -> str:
    return f"{float(timestamp):.6f}"


def save_instances(path: Path, instances: list[PersonInstance], shape: tuple[int, int], timestamp: float) -> None:
    k = len(instances)
    masks = (np.stack([p.mask for p in instances]).astype(bool) if k else np.zeros((0, *shape), bool))
    arrays = {
        "bits": np.packbits(masks, axis=None),
        "shape": np.asarray(masks.shape, dtype=np.int64),
        "scores": np.asarray([p.score for p in instances], dtype=np.float32).reshape(k),
        "boxes": np.asarray([p.box for p in instances], dtype=np.float32).reshape(k, 4),
        "timestamp": np.float64(timestamp),
    }
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f"{temp_tag()}-", suffix=".npz")
    try:
        with os.fdopen(fd, "wb") as fh:
            np.savez_compressed(fh, **arrays)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def load_instances(path: Path, timestamp: float | None = None) -> list[PersonInstance]:
    """Read one cache file; ``ValueError`` (or an I/O error) when it is corrupt or inconsistent."""
    with np.load(path, allow_pickle=False) as data:
        bits, shape = data["bits"], tuple(int(v) for v in data["shape"])
        scores, boxes, ts = data["scores"], data["boxes"], float(data["timestamp"])
    if len(shape) != 3 or min(shape) < 0 or shape[1] < 1 or shape[2] < 1:
        raise ValueError(f"bad mask shape {shape}")
    k = shape[0]
    if bits.dtype != np.uint8 or bits.size != (k * shape[1] * shape[2] + 7) // 8:
        raise ValueError("packed mask size does not match its shape")
    if scores.shape != (k,) or boxes.shape != (k, 4):
        raise ValueError("scores/boxes do not match the number of masks")
    if timestamp is not None and timestamp_stem(ts) != timestamp_stem(timestamp):
        raise ValueError(f"file holds timestamp {ts}, expected {timestamp}")
    masks = np.unpackbits(bits, count=k * shape[1] * shape[2]).astype(bool).reshape(shape)
    return [PersonInstance(mask=m, score=float(s), box=tuple(float(v) for v in b))
            for m, s, b in zip(masks, scores, boxes)]


class CachedSegmenter:
    """Wraps a segmenter for one sequence: ``instances(i)`` / ``__call__(frame)`` read the cache and segment (then
    store) only on a miss. Segmenters with ``cacheable = False`` (the label readers) are passed through.
    ``hits``, ``misses`` and ``recovered`` count what happened."""

    def __init__(self, segmenter, sequence, root: str | Path | None = None):
        self.segmenter = segmenter
        self.sequence = sequence
        self.name = segmenter.name
        self.cacheable = getattr(segmenter, "cacheable", True)
        self.hits = self.misses = self.recovered = 0
        self.dir = None
        if self.cacheable:
            seq_key, seg_key = sequence_key(sequence), segmenter_key(segmenter)
            self.dir = (Path(root) / seq_key / seg_key) if root is not None else cache_dir("masks", seq_key, seg_key)
            self.dir.mkdir(parents=True, exist_ok=True)
            meta = self.dir / "meta.json"
            if not meta.is_file():
                meta.write_text(json.dumps({"sequence": str(Path(sequence.root).resolve()),
                                            "segmenter": segmenter.identity()}, indent=1, sort_keys=True))

    def path_for(self, timestamp: float) -> Path:
        return self.dir / f"{timestamp_stem(timestamp)}.npz"

    def _lookup(self, timestamp: float) -> list[PersonInstance] | None:
        path = self.path_for(timestamp)
        if not path.is_file():
            return None
        try:
            return load_instances(path, timestamp)
        except (ValueError, KeyError, OSError, EOFError, zipfile.BadZipFile) as exc:
            warnings.warn(f"{path}: corrupt mask cache file ({type(exc).__name__}: {exc}); recomputing", stacklevel=3)
            self.recovered += 1
            return None

    def _compute(self, frame) -> list[PersonInstance]:
        persons = self.segmenter(frame)
        self.misses += 1
        path = self.path_for(frame.timestamp)
        try:
            save_instances(path, persons, frame.rgb.shape[:2], frame.timestamp)
        except OSError as exc:
            raise D2SlamError(f"cannot write the mask cache ({exc.strerror or exc}); set $D2SLAM_CACHE to a "
                              "writable folder", path=path) from None
        return persons

    def instances(self, index: int) -> list[PersonInstance]:
        """Persons of frame ``index`` (the frame's images are read only on a miss)."""
        if not self.cacheable:
            inst = getattr(self.segmenter, "instances", None)
            return inst(index) if inst is not None else self.segmenter(self.sequence[index])
        cached = self._lookup(self.sequence.timestamps[index])
        if cached is not None:
            self.hits += 1
            return cached
        return self._compute(self.sequence[index])

    def __call__(self, frame) -> list[PersonInstance]:
        if not self.cacheable:
            return self.segmenter(frame)
        cached = self._lookup(frame.timestamp)
        if cached is not None:
            self.hits += 1
            return cached
        return self._compute(frame)

    def missing(self, frames: int | None = None) -> list[int]:
        """Indices of the first ``frames`` frames (all by default) whose masks are not in the cache yet."""
        n = len(self.sequence) if frames is None else min(len(self.sequence), int(frames))
        return [i for i in range(n) if not self.path_for(self.sequence.timestamps[i]).is_file()]

    def fill(self, progress: bool = True, frames: int | None = None, recheck: bool = True) -> tuple[int, int]:
        """Segment the first ``frames`` frames (all by default) not yet cached; ``recheck`` also reads the cached ones
        (a corrupt file is recomputed). With ``progress`` the segmentation is announced with an estimate
        (``CliConfig.segment_frame_s``) and followed (:mod:`d2slam.progress`). Returns (hits, misses) of this
        call."""
        from d2slam.config import CLI
        from d2slam.progress import announce
        from d2slam.progress import progress as follow

        if not self.cacheable:
            raise D2SlamError(f"the '{self.name}' masks are read from the sequence and need no cache")
        n = len(self.sequence) if frames is None else min(len(self.sequence), int(frames))
        todo = self.missing(n)
        if todo and progress:
            model = getattr(self.segmenter, "model_path", None)
            announce(f"segmenting {len(todo)} frames of {self.sequence.name} with "
                     f"{Path(model).name if model else self.name} into the mask cache {self.dir} (once per "
                     "sequence)", len(todo) * CLI.segment_frame_s)
        h0, m0 = self.hits, self.misses
        for i in follow(range(n) if recheck else todo, desc=f"segment {self.sequence.name}",
                        enabled=progress and bool(todo)):
            self.instances(i)
        return self.hits - h0 + (0 if recheck else n - len(todo)), self.misses - m0

class RgbListSequence:
    """Every RGB image listed in a TUM ``rgb.txt`` (parsed by ``d2slam.data.tum.read_file_list``; no depth, no
    association): what ``d2slam segment SEQUENCE_DIR`` fills the cache for. The cache key depends only on the folder, ``rgb.txt`` and the timestamps,
    so masks cached through this reader are hits for the full TUM/synthetic readers too. Frames carry an empty
    (0, 0) depth."""

    def __init__(self, root: str | Path):
        self.root = Path(root)
        self.name = self.root.resolve().name
        path = self.root / "rgb.txt"
        if not path.is_file():
            raise D2SlamError("not a TUM sequence folder: rgb.txt not found", path=path)
        from d2slam.data.tum import read_file_list

        stamps, names, _ = read_file_list(path)  # D2SlamError naming the line on bad rows / order
        if not len(stamps):
            raise D2SlamError("rgb.txt lists no images", path=path)
        files = [p if p.is_absolute() else self.root / p for p in map(Path, names)]
        self.timestamps = np.asarray(stamps, dtype=np.float64)
        self.rgb_paths = files

    def __len__(self) -> int:
        return len(self.timestamps)

    def __getitem__(self, index: int):
        from d2slam.data.base import RGBDFrame
        from d2slam.segmentation.onnx import read_rgb

        if not -len(self) <= index < len(self):
            raise IndexError(index)
        index %= len(self)
        ts = float(self.timestamps[index])
        return RGBDFrame(index=index, timestamp=ts, depth_timestamp=ts, rgb=read_rgb(self.rgb_paths[index]),
                     depth=np.zeros((0, 0), np.float32), rgb_path=self.rgb_paths[index])

    def __iter__(self):
        return (self[i] for i in range(len(self)))
