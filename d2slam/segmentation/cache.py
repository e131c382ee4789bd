"""Mask cache, so that runs and ablations never segment a frame twice, and read a frame's masks in well under a
millisecond.

Layout: ``cache_dir("masks", <sequence key>, <segmenter key>)/masks.npz``, one file per sequence and segmenter:

* sequence key = ``<folder name>-<sha256(resolved root path + sha256(rgb.txt) + the images' content)[:16]>`` (the
  timestamps when there is no ``rgb.txt``): a moved or edited sequence, or one whose images were replaced, gets a
  new key. The images' content (:func:`images_digest`) is the sha256 of every image listed in ``rgb.txt``, found
  again cheaply from their names, sizes and modification times (a memo per folder, ``stamps/``); the images are
  hashed in full when those changed or were never seen, and when the memo was written within
  ``CacheConfig.cache_mtime_window_s`` of an image's last modification (a change in that window could keep the same
  time on a file system with coarse timestamps). So replaced images are never read with the old masks, and
  touched or copied ones (same bytes, new times) keep them;
* segmenter key = ``<kind>-<sha256(identity)[:16]>`` where ``identity()`` holds the model's sha256 (the model file,
  which also fixes its input size), the decoder version and every config value that changes masks (score
  threshold, NMS IoU, mask threshold, dilation, max persons; not the thread count): another model, input size or
  config never reads stale masks;
* ``masks.npz`` (``FORMAT``; ``np.savez_compressed``, decompressed once when read): ``format``, ``shape`` (H, W) of the frames, ``timestamps``
  (n,) ascending (the cached frames' RGB timestamps), ``first`` (n + 1,): frame f holds instances
  ``first[f]:first[f + 1]``; per instance ``scores`` (m,), ``boxes`` (m, 4), ``rects`` (m, 4) int32 ``x, y, w, h``
  of the rectangle its mask is stored in (the mask's bounding rectangle: False outside it) and its bits,
  ``bits[offsets[j]:offsets[j + 1]]``, the ``np.packbits`` of that rectangle (row-major).

Person masks cover a small part of a frame, so the file is small and a frame is decoded by unpacking its rectangles
into zeroed masks: no decompression and no file access per frame (``d2slam bench segmenter_speed --cache SEQ``). The
file is read once per process and sequence (``MaskStore``). Frames segmented since are written by rewriting the file
atomically (a temporary file named after the writing process, :mod:`d2slam.outputs`, then a rename; under a lock
file, merged with what other processes added meanwhile): every
``SegmentationConfig.cache_flush_frames`` new frames, when every frame of the sequence is cached, at the end of
``CachedSegmenter.fill`` and at exit. ``fill`` (what a run, ``d2slam segment SEQ`` and the study segment through)
holds a second lock (``segment.lock``) while it segments: a second process asking for the same sequence waits,
says so, then reads the first one's masks instead of segmenting them again. A damaged or inconsistent file is
reported in one line naming it (:func:`d2slam.cachefiles.report_damaged`), and its frames are recomputed and the file
rewritten (documented recovery). A folder of the earlier layout (one compressed ``<timestamp>.npz`` per frame) is
converted on first use; its files are left in place.
"""

from __future__ import annotations

import atexit
import hashlib
import json
import os
import tempfile
import time
import weakref
import zipfile
from pathlib import Path

import numpy as np
from tqdm import tqdm

from d2slam.cachefiles import CACHE, Damaged, load_npz, read_json, report_damaged, sealed, sha256_file, unsealed
from d2slam.data.base import RGBDFrame
from d2slam.data.tum import read_file_list
from d2slam.errors import D2SlamError
from d2slam.outputs import file_lock, remove_stale_temps, temp_tag, write_bytes
from d2slam.paths import cache_dir
from d2slam.progress import PROGRESS, announce, progress as follow
from d2slam.segmentation.base import PersonInstance
from d2slam.segmentation.config import SegmentationConfig
from d2slam.segmentation.onnx import read_rgb

FORMAT = "d2slam-masks/2"
STORE_NAME = "masks.npz"
_ARRAYS = ("format", "shape", "timestamps", "first", "scores", "boxes", "rects", "offsets", "bits")


def _digest(blob: bytes) -> str:
    return hashlib.sha256(blob).hexdigest()


def sequence_key(sequence) -> str:
    """Identity of a sequence: its name, resolved root, the content of ``rgb.txt`` and of the images it lists
    (:func:`images_digest`); without ``rgb.txt``, its timestamps."""
    root = Path(sequence.root).resolve()
    rgb_txt = root / "rgb.txt"
    if rgb_txt.is_file():
        content = f"{_digest(rgb_txt.read_bytes())}|{images_digest(root)}"
    else:
        content = _digest(np.ascontiguousarray(np.asarray(sequence.timestamps, dtype=np.float64)).tobytes())
    name = "".join(c if c.isalnum() or c in "-_." else "_" for c in root.name)
    return f"{name[:60]}-{_digest(f'{root}|{content}'.encode())[:16]}"


def _listed_images(root: Path) -> list[Path]:
    _, names, _ = read_file_list(root / "rgb.txt")  # D2SlamError naming the line on a bad row
    return [p if p.is_absolute() else root / p for p in map(Path, names)]


def images_digest(root: str | Path, window_s: float | None = None) -> str:
    """sha256 of the content of every image ``root/rgb.txt`` lists (with its name): from the memo
    ``cache_dir("masks", "stamps", <root digest>.json)`` when the images' names, sizes and modification times are
    those it recorded and it was written at least ``window_s`` (``CacheConfig.cache_mtime_window_s``) after the newest
    of them was modified; otherwise every image is hashed and the memo rewritten. The memo is sealed
    (:func:`d2slam.cachefiles.sealed`): a damaged one is said and made again. A missing image counts by its name."""
    root = Path(root).resolve()
    window = CACHE.cache_mtime_window_s if window_s is None else window_s
    images = _listed_images(root)
    stats = []
    for p in images:
        try:
            st = p.stat()
            stats.append([str(p), st.st_size, st.st_mtime_ns])
        except OSError:
            stats.append([str(p), -1, 0])
    stat = _digest(json.dumps(stats).encode())
    memo_path = cache_dir("masks", "stamps") / f"{_digest(str(root).encode())[:16]}.json"
    newest = max((m for _, _, m in stats), default=0)
    try:
        memo = unsealed(read_json(memo_path))
        if memo.get("stat") == stat and memo.get("recorded_ns", 0) - newest >= window * 1e9 and \
                isinstance(memo.get("content"), str):
            return memo["content"]
    except FileNotFoundError:
        pass
    except Damaged as exc:
        report_damaged(memo_path, "mask cache memo", exc, "hashing the images again")
    h = hashlib.sha256()
    for p, (_, size, _) in zip(images, stats):
        h.update(f"{p.relative_to(root) if p.is_relative_to(root) else p}|".encode())
        h.update((sha256_file(p) if size >= 0 else "missing").encode())
    content = h.hexdigest()

    try:
        write_bytes(memo_path, json.dumps(sealed({"root": str(root), "stat": stat, "content": content,
                                                  "recorded_ns": time.time_ns()})))
    except D2SlamError:  # a read-only cache: hashed again next time
        pass
    return content


def segmenter_key(segmenter) -> str:
    ident = segmenter.identity()
    return f"{ident.get('kind', segmenter.name)}-{_digest(json.dumps(ident, sort_keys=True).encode())[:16]}"


def timestamp_stem(timestamp: float) -> str:
    return f"{float(timestamp):.6f}"


# ---------------------------------------------------------------------------------------------- one frame's record
def encode_mask(mask: np.ndarray) -> tuple[tuple[int, int, int, int], np.ndarray]:
    """``((x, y, w, h), bits)``: a (H, W) mask's bounding rectangle and the packed bits of the mask inside it
    (``(0, 0, 0, 0)`` and no bits for an empty mask)."""
    m = np.asarray(mask, dtype=bool)
    rows = np.flatnonzero(m.any(axis=1))
    if len(rows) == 0:
        return (0, 0, 0, 0), np.zeros(0, np.uint8)
    cols = np.flatnonzero(m.any(axis=0))
    y0, y1, x0, x1 = int(rows[0]), int(rows[-1]) + 1, int(cols[0]), int(cols[-1]) + 1
    return (x0, y0, x1 - x0, y1 - y0), np.packbits(m[y0:y1, x0:x1], axis=None)


class FrameRecord:
    """One frame's instances as stored: ``scores`` (k,) float32, ``boxes`` (k, 4) float32, ``rects`` (k tuples
    x, y, w, h), ``bits`` (k uint8 arrays)."""

    __slots__ = ("timestamp", "scores", "boxes", "rects", "bits")

    def __init__(self, timestamp: float, scores: np.ndarray, boxes: np.ndarray, rects: list, bits: list):
        self.timestamp, self.scores, self.boxes, self.rects, self.bits = float(timestamp), scores, boxes, rects, bits

    @classmethod
    def from_instances(cls, timestamp: float, instances: list[PersonInstance]) -> "FrameRecord":
        k = len(instances)
        encoded = [encode_mask(p.mask) for p in instances]
        return cls(timestamp, np.asarray([p.score for p in instances], dtype=np.float32).reshape(k),
                   np.asarray([p.box for p in instances], dtype=np.float32).reshape(k, 4),
                   [r for r, _ in encoded], [b for _, b in encoded])

    def instances(self, shape: tuple[int, int]) -> list[PersonInstance]:
        """The frame's persons, masks at ``shape`` (one (k, H, W) array; each instance holds a view of it)."""
        k = len(self.rects)
        if k == 0:
            return []
        masks = np.zeros((k, *shape), dtype=bool)
        for j, (x, y, w, h) in enumerate(self.rects):
            if w:
                masks[j, y:y + h, x:x + w] = np.unpackbits(self.bits[j], count=w * h).reshape(h, w).view(bool)
        boxes = self.boxes.tolist()
        return [PersonInstance(mask=masks[j], score=float(s), box=tuple(boxes[j]))
                for j, s in enumerate(self.scores.tolist())]


# ---------------------------------------------------------------------------------------------- the file
def read_store(path: Path) -> tuple[tuple[int, int], dict[str, FrameRecord]]:
    """``(shape, {timestamp stem: FrameRecord})`` of a ``masks.npz``; :class:`~d2slam.cachefiles.Damaged` (or
    ``ValueError``) when it is damaged or inconsistent."""
    a = load_npz(path, _ARRAYS)
    if str(a["format"]) != FORMAT:
        raise ValueError(f"format {a['format']!s} is not {FORMAT}")
    shape = tuple(int(v) for v in a["shape"].reshape(-1))
    ts, first = a["timestamps"], a["first"]
    scores, boxes, rects, offsets, bits = a["scores"], a["boxes"], a["rects"], a["offsets"], a["bits"]
    n, m = len(ts), len(scores)
    if len(shape) != 2 or min(shape) < 1:
        raise ValueError(f"bad frame shape {shape}")
    if ts.ndim != 1 or not np.all(np.isfinite(ts)) or np.any(np.diff(ts) <= 0):
        raise ValueError("timestamps are not finite and strictly increasing")
    if first.shape != (n + 1,) or first[0] != 0 or first[-1] != m or np.any(np.diff(first) < 0):
        raise ValueError("frame ranges do not match the instances")
    if scores.shape != (m,) or boxes.shape != (m, 4) or rects.shape != (m, 4) or offsets.shape != (m + 1,):
        raise ValueError("instance arrays do not match in length")
    x, y, w, h = rects.T.astype(np.int64)
    if np.any(rects < 0) or np.any(x + w > shape[1]) or np.any(y + h > shape[0]) or np.any((w == 0) != (h == 0)):
        raise ValueError("a mask rectangle lies outside the frame")
    if bits.dtype != np.uint8 or offsets[0] != 0 or offsets[-1] != len(bits) or \
            np.any(np.diff(offsets) != (w * h + 7) // 8):
        raise ValueError("packed mask sizes do not match their rectangles")
    rect_list, off = rects.tolist(), offsets.tolist()
    chunks = [bits[off[j]:off[j + 1]] for j in range(m)]
    frames = {}
    for f, (t, a0, a1) in enumerate(zip(ts.tolist(), first[:-1].tolist(), first[1:].tolist())):
        frames[timestamp_stem(t)] = FrameRecord(t, scores[a0:a1], boxes[a0:a1], rect_list[a0:a1], chunks[a0:a1])
    return shape, frames


def write_store(path: Path, shape: tuple[int, int], frames: dict[str, FrameRecord]) -> None:
    """Write every frame of ``frames`` (sorted by timestamp) into ``path`` atomically (temporary file + rename)."""
    recs = sorted(frames.values(), key=lambda r: r.timestamp)
    counts = [len(r.rects) for r in recs]
    rects = [rect for r in recs for rect in r.rects]
    chunks = [b for r in recs for b in r.bits]
    arrays = {
        "format": np.array(FORMAT),
        "shape": np.asarray(shape, dtype=np.int64),
        "timestamps": np.asarray([r.timestamp for r in recs], dtype=np.float64),
        "first": np.concatenate([[0], np.cumsum(counts, dtype=np.int64)]).astype(np.int64),
        "scores": np.concatenate([r.scores for r in recs] or [np.zeros(0)]).astype(np.float32),
        "boxes": np.concatenate([r.boxes for r in recs] or [np.zeros((0, 4))]).astype(np.float32).reshape(-1, 4),
        "rects": np.asarray(rects, dtype=np.int32).reshape(-1, 4),
        "offsets": np.concatenate([[0], np.cumsum([len(b) for b in chunks], dtype=np.int64)]).astype(np.int64),
        "bits": np.concatenate(chunks or [np.zeros(0, np.uint8)]).astype(np.uint8),
    }
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f"{temp_tag()}-", suffix=".npz")
    try:
        with os.fdopen(fd, "wb") as fh:
            np.savez_compressed(fh, **arrays)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def _stamp(path: Path):
    try:
        st = path.stat()
    except OSError:
        return None
    return (st.st_ino, st.st_size, st.st_mtime_ns)


_LIVE: "weakref.WeakSet[MaskStore]" = weakref.WeakSet()


@atexit.register
def _flush_at_exit() -> None:
    for store in list(_LIVE):
        try:
            store.flush()
        except (D2SlamError, OSError):  # the frames are recomputed by the next run
            pass


class MaskStore:
    """The cached frames of one (sequence, segmenter): ``masks.npz`` read once, frames added in memory (``put``) and
    written by ``flush`` (see the module docstring). ``recovered`` is 1 when the file was corrupt."""

    def __init__(self, path: str | Path):
        self.path = Path(path)
        self.shape: tuple[int, int] | None = None
        self.frames: dict[str, FrameRecord] = {}
        self.pending = 0
        self.recovered = 0
        self._stamp = None
        self._load()
        _LIVE.add(self)

    def _load(self) -> None:
        stamp = _stamp(self.path)
        if stamp is None:
            return
        try:
            shape, frames = read_store(self.path)
        except (Damaged, ValueError, KeyError, OSError, EOFError, zipfile.BadZipFile) as exc:
            report_damaged(self.path, "mask cache file", exc, "segmenting its frames again")
            self.recovered = 1
            self.pending = max(self.pending, 1)  # rewritten on the next flush even if nothing new is segmented
            return
        self.shape, self._stamp = shape, stamp
        self.frames = {**frames, **self.frames}

    def reload(self) -> None:
        """Read the frames another process wrote since this one read the file (this one's are kept)."""
        if _stamp(self.path) != self._stamp and not self.recovered:
            self._load()

    def __len__(self) -> int:
        return len(self.frames)

    def __contains__(self, timestamp: float) -> bool:
        return timestamp_stem(timestamp) in self.frames

    def get(self, timestamp: float) -> list[PersonInstance] | None:
        """The persons of the frame at ``timestamp``, or None when it is not cached."""
        rec = self.frames.get(timestamp_stem(timestamp))
        return None if rec is None else rec.instances(self.shape)

    def put(self, timestamp: float, instances: list[PersonInstance], shape: tuple[int, int]) -> None:
        shape = (int(shape[0]), int(shape[1]))
        if self.shape is None or not self.frames:
            self.shape = shape
        elif shape != self.shape:
            raise D2SlamError(f"frame at {timestamp_stem(timestamp)} has size {shape}, the cached frames "
                              f"{self.shape}", path=self.path)
        self.frames[timestamp_stem(timestamp)] = FrameRecord.from_instances(timestamp, instances)
        self.pending += 1

    def flush(self) -> None:
        """Write the frames added since the last write (merged with frames other processes wrote meanwhile)."""
        if not self.pending:
            return
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            with file_lock(self.path.with_name(self.path.name + ".lock")):
                if not self.recovered and _stamp(self.path) != self._stamp:
                    self._load()  # another process wrote frames: keep them (ours take precedence)
                write_store(self.path, self.shape or (1, 1), self.frames)
                self._stamp = _stamp(self.path)
        except OSError as exc:
            raise D2SlamError(f"cannot write the mask cache ({exc.strerror or exc}); set $D2SLAM_CACHE to a "
                              "writable folder", path=self.path) from None
        self.pending = 0
        self.recovered = 0


# ---------------------------------------------------------------------------------------------- the earlier layout
def load_frame_file(path: Path, timestamp: float | None = None) -> list[PersonInstance]:
    """Read one ``<timestamp>.npz`` of the earlier per-frame layout (``bits``, ``shape``, ``scores``, ``boxes``,
    ``timestamp``); ``ValueError`` (or an I/O error) when it is corrupt or inconsistent."""
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


def convert_frame_files(folder: Path, store: MaskStore, timestamps, progress: bool = True) -> int:
    """Add the ``<timestamp>.npz`` files of ``folder`` (earlier layout) for ``timestamps`` to ``store`` (unreadable
    files are skipped: recomputed later); returns how many were added."""
    files = [(t, folder / f"{timestamp_stem(t)}.npz") for t in np.asarray(timestamps, dtype=np.float64).tolist()]
    files = [(t, p) for t, p in files if t not in store and p.is_file()]
    added = 0
    for t, p in tqdm(files, desc="convert mask cache", unit="frame", disable=None if progress else True):
        try:
            persons = load_frame_file(p, t)
        except (ValueError, KeyError, OSError, EOFError, zipfile.BadZipFile):
            continue
        shape = persons[0].mask.shape if persons else store.shape
        if shape is None:  # no person in the frame: the size comes from the file
            with np.load(p, allow_pickle=False) as data:
                shape = tuple(int(v) for v in data["shape"][1:])
        store.put(t, persons, shape)
        added += 1
    return added


# ---------------------------------------------------------------------------------------------- the segmenter
class CachedSegmenter:
    """Wraps a segmenter for one sequence: ``instances(i)`` / ``__call__(frame)`` read the cache and segment (then
    store) only on a miss. Segmenters with ``cacheable = False`` (the label readers) are passed through.
    ``hits``, ``misses`` and ``recovered`` count what happened; ``flush_frames``: new frames between two writes of
    the cache file (default ``SegmentationConfig.cache_flush_frames``)."""

    def __init__(self, segmenter, sequence, root: str | Path | None = None, flush_frames: int | None = None):
        self.segmenter = segmenter
        self.sequence = sequence
        self.name = segmenter.name
        self.cacheable = getattr(segmenter, "cacheable", True)
        self.hits = self.misses = self.recovered = 0
        self.flush_frames = int(flush_frames or SegmentationConfig().cache_flush_frames)
        self.dir = self.store = None
        if self.cacheable:
            seq_key, seg_key = sequence_key(sequence), segmenter_key(segmenter)
            self.dir = (Path(root) / seq_key / seg_key) if root is not None else cache_dir("masks", seq_key, seg_key)
            try:
                self.dir.mkdir(parents=True, exist_ok=True)
            except OSError as exc:
                raise D2SlamError(f"cannot write the mask cache ({exc.strerror or exc}); set $D2SLAM_CACHE to a "
                                  "writable folder", path=self.dir) from None
            remove_stale_temps(self.dir)  # what a killed process was writing (the mask file, meta.json)
            self._write_meta()
            path = self.dir / STORE_NAME
            fresh = not path.exists()
            self.store = MaskStore(path)
            self.recovered = self.store.recovered
            self._wanted = {timestamp_stem(t) for t in np.asarray(sequence.timestamps, dtype=np.float64).tolist()}
            if fresh and convert_frame_files(self.dir, self.store, sequence.timestamps):
                self.store.flush()
            self._missing = len(self._wanted - set(self.store.frames))

    def _write_meta(self) -> None:
        meta = self.dir / "meta.json"
        if meta.is_file():
            return
        text = json.dumps({"sequence": str(Path(self.sequence.root).resolve()), "format": FORMAT,
                           "segmenter": self.segmenter.identity()}, indent=1, sort_keys=True)
        try:
            write_bytes(meta, text)
        except D2SlamError as exc:
            raise D2SlamError(f"cannot write the mask cache ({getattr(exc, 'reason', exc)}); set $D2SLAM_CACHE to "
                              "a writable folder", path=meta) from None

    def _lookup(self, timestamp: float) -> list[PersonInstance] | None:
        found = self.store.get(timestamp)
        if found is not None:
            self.hits += 1
        return found

    def _compute(self, frame) -> list[PersonInstance]:
        persons = self.segmenter(frame)
        self.misses += 1
        stem = timestamp_stem(frame.timestamp)
        new = stem in self._wanted and stem not in self.store.frames
        self.store.put(frame.timestamp, persons, frame.rgb.shape[:2])
        self._missing -= int(new)
        if self.store.pending >= self.flush_frames or self._missing <= 0:
            self.store.flush()
        return persons

    def instances(self, index: int) -> list[PersonInstance]:
        """Persons of frame ``index`` (the frame's images are read only on a miss)."""
        if not self.cacheable:
            inst = getattr(self.segmenter, "instances", None)
            return inst(index) if inst is not None else self.segmenter(self.sequence[index])
        cached = self._lookup(self.sequence.timestamps[index])
        if cached is not None:
            return cached
        read = getattr(self.sequence, "rgb_frame", None)  # the colour image alone, where the sequence can
        return self._compute(read(index) if read is not None else self.sequence[index])

    def __call__(self, frame) -> list[PersonInstance]:
        if not self.cacheable:
            return self.segmenter(frame)
        cached = self._lookup(frame.timestamp)
        if cached is not None:
            return cached
        return self._compute(frame)

    def flush(self) -> None:
        """Write the frames segmented since the last write into the cache file."""
        if self.store is not None:
            self.store.flush()

    def missing(self, frames: int | None = None) -> list[int]:
        """Indices of the first ``frames`` frames (all by default) whose masks are not in the cache yet."""
        n = len(self.sequence) if frames is None else min(len(self.sequence), int(frames))
        return [i for i in range(n) if self.sequence.timestamps[i] not in self.store]

    def fill(self, progress: bool = True, frames: int | None = None, recheck: bool = True) -> tuple[int, int]:
        """Segment the first ``frames`` frames (all by default) not yet cached, then write the cache file; ``recheck``
        also decodes the cached ones. With ``progress`` the segmentation is announced with an estimate
        (``ProgressConfig.segment_frame_s``) and followed (:mod:`d2slam.progress`). Segmenting holds the sequence's
        ``segment.lock``: a second process waits for the first and reads its masks. Returns (hits, misses) of this
        call."""
        if not self.cacheable:
            raise D2SlamError(f"the '{self.name}' masks are read from the sequence and need no cache")
        n = len(self.sequence) if frames is None else min(len(self.sequence), int(frames))
        if not self.missing(n):
            return self._fill(n, [], progress, recheck)
        name = getattr(self.sequence, "name", Path(self.sequence.root).name)
        with file_lock(self.dir / "segment.lock",
                       waiting=f"d2slam: another process is segmenting {name} into the mask cache {self.dir}; "
                               "waiting for it, then reading its masks"):
            self.store.reload()  # what that process segmented meanwhile
            return self._fill(n, self.missing(n), progress, recheck)

    def _fill(self, n: int, todo: list[int], progress: bool, recheck: bool) -> tuple[int, int]:
        if todo and progress:
            model = getattr(self.segmenter, "model_path", None)
            announce(f"segmenting {len(todo)} frames of {self.sequence.name} with "
                     f"{Path(model).name if model else self.name} into the mask cache {self.dir} (once per "
                     "sequence)", len(todo) * PROGRESS.segment_frame_s)
        h0, m0 = self.hits, self.misses
        for i in follow(range(n) if recheck else todo, desc=f"segment {self.sequence.name}",
                        enabled=progress and bool(todo)):
            self.instances(i)
        self.store.flush()
        return self.hits - h0 + (0 if recheck else n - len(todo)), self.misses - m0


class RgbListSequence:
    """Every RGB image listed in a TUM ``rgb.txt`` (parsed by ``d2slam.data.tum.read_file_list``; no depth, no
    association): what ``d2slam segment SEQUENCE_DIR`` fills the cache for. The cache key depends only on the folder,
    ``rgb.txt`` and the images it lists, so masks cached through this reader are hits for the full TUM/synthetic
    readers too. Frames carry an empty (0, 0) depth."""

    def __init__(self, root: str | Path):
        self.root = Path(root)
        self.name = self.root.resolve().name
        path = self.root / "rgb.txt"
        if not path.is_file():
            raise D2SlamError("not a TUM sequence folder: rgb.txt not found", path=path)

        stamps, names, _ = read_file_list(path)  # D2SlamError naming the line on bad rows / order
        if not len(stamps):
            raise D2SlamError("rgb.txt lists no images", path=path)
        files = [p if p.is_absolute() else self.root / p for p in map(Path, names)]
        self.timestamps = np.asarray(stamps, dtype=np.float64)
        self.rgb_paths = files

    def __len__(self) -> int:
        return len(self.timestamps)

    def __getitem__(self, index: int):
        if not -len(self) <= index < len(self):
            raise IndexError(index)
        index %= len(self)
        ts = float(self.timestamps[index])
        return RGBDFrame(index=index, timestamp=ts, depth_timestamp=ts, rgb=read_rgb(self.rgb_paths[index]),
                     depth=np.zeros((0, 0), np.float32), rgb_path=self.rgb_paths[index])

    def __iter__(self):
        return (self[i] for i in range(len(self)))
