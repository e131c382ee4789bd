"""A sequence's extracted features, stored once and reused by every run on it.

A frame's features (bucketed ORB, per-keypoint depth and virtual right coordinate: :class:`OrbExtractor`) depend
only on its images, the camera, the ORB and engine settings and the code, never on the method that consumes them.
The study runs seven methods on every sequence; each sequence's features are extracted by the first run and read
from the cache by the others. The frames rebuilt from the cache are bit-identical to freshly extracted ones, so a
run gives the same trajectory either way (``tests/test_features_cache.py``).

Timing: a run that reads the cache reports, as its ``extract`` stage, the milliseconds the extraction of each frame
took when the cache was written, and its fps counts that time instead of the (near zero) read: the reported speed
remains the speed of a run that extracts. Without a keypoint filter such a run does not decode the images at all,
so its ``load`` stage is shorter than a plain run's.

Storage: one ``.npz`` per sequence, the per-frame arrays concatenated with per-frame offsets, the frame timestamps
(checked on reading) and the per-frame extraction milliseconds; written to a temporary file (named after the
writing process: :mod:`d2slam.outputs`) and renamed, so concurrent workers never read half a file. The study names
the file after the sequence and a digest of what an extraction depends on (:func:`d2slam.study.runner.features_path`).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from d2slam.cachefiles import Damaged, load_npz
from d2slam.errors import D2SlamError
from d2slam.outputs import staged_file
from d2slam.slam.frame import Frame

FORMAT = "d2slam-features/1"
FIELDS = ("kps", "kps_raw", "octave", "angle", "desc", "depth", "ur", "inv_sigma2")


class FeatureRecorder:
    """Collects each frame's features as the engine extracts them (``add``), then ``save``s them."""

    def __init__(self):
        self.frames: list[dict[str, np.ndarray]] = []
        self.timestamps: list[float] = []
        self.extract_ms: list[float] = []

    def add(self, frame: Frame, extract_s: float) -> None:
        if frame.index != len(self.frames):
            raise D2SlamError(f"features must be recorded in frame order (got frame {frame.index} after "
                              f"{len(self.frames)} frames)")
        self.frames.append({k: np.array(getattr(frame, k), copy=True) for k in FIELDS})
        self.timestamps.append(float(frame.timestamp))
        self.extract_ms.append(1000.0 * float(extract_s))

    def save(self, path: str | Path) -> Path:
        path = Path(path)
        if not self.frames:
            raise D2SlamError("no features to save", path=path)
        arrays = {k: np.concatenate([f[k] for f in self.frames]) for k in FIELDS}
        counts = np.array([len(f["kps"]) for f in self.frames], dtype=np.int64)
        path.parent.mkdir(parents=True, exist_ok=True)
        with staged_file(path, ".npz") as tmp:
            np.savez(tmp, format=np.array(FORMAT), offsets=np.r_[0, np.cumsum(counts)],
                     timestamps=np.asarray(self.timestamps), extract_ms=np.asarray(self.extract_ms), **arrays)
        return path


class CachedFeatures:
    """Frames rebuilt from a saved feature file (fresh arrays on every call: the engine mutates its frames)."""

    def __init__(self, path: str | Path):
        """:class:`~d2slam.cachefiles.Damaged` when the file cannot be read in full or its arrays disagree."""
        self.path = Path(path)
        z = load_npz(self.path, ("format", "offsets", "timestamps", "extract_ms") + FIELDS)
        if str(z["format"]) != FORMAT:
            raise Damaged(f"not a {FORMAT} feature file")
        self._arrays = {k: z[k] for k in FIELDS}
        self.offsets, self.timestamps, self.extract_ms = z["offsets"], z["timestamps"], z["extract_ms"]
        n = len(self.timestamps)
        if len(self.offsets) != n + 1 or len(self.extract_ms) != n or \
                any(len(a) != self.offsets[-1] for a in self._arrays.values()):
            raise Damaged("inconsistent array lengths")

    def __len__(self) -> int:
        return len(self.timestamps)

    def check(self, timestamps) -> None:
        """Raise unless the file holds exactly the frames with these timestamps."""
        ts = np.asarray(timestamps, dtype=np.float64)
        if len(ts) != len(self) or not np.array_equal(ts, self.timestamps):
            raise Damaged(f"it does not match the sequence ({len(self)} frames stored, {len(ts)} in the sequence)")

    def frame(self, index: int) -> Frame:
        a, b = int(self.offsets[index]), int(self.offsets[index + 1])
        return Frame(index=index, timestamp=float(self.timestamps[index]),
                     **{k: self._arrays[k][a:b].copy() for k in FIELDS})
