"""Run a sequence through the SLAM engine: one function, a progress bar, per-stage timings, a result object.

    run = run_sequence(open_sequence(path), keypoint_filter=None, mask_provider=None)
    run.trajectory  # tracked frames only (T_world_camera), run.tracked / run.lost, run.fps (run.record.EngineRun)

Stages timed per frame: ``load`` (waiting for the images and masks; the next two frames and their masks are read by
one prefetch thread while the current one is processed), ``segment`` (the mask provider's own time, when there is
one; in the prefetch thread, overlapping the other stages, unless ``prefetch=False``), ``extract`` (ORB + depth;
the next frame's extraction runs in the engine's worker thread while this one is tracked, so it overlaps the
other stages and the stages add up to more than the wall time), ``filter`` (frame-to-frame matches + the hook),
``track`` (all tracking steps), ``local_ba`` (new keyframe + local mapping), ``loop`` (the keyframe database, loop
detection and correction).

``features``: a :class:`~d2slam.slam.features.FeatureRecorder` keeps every frame's extracted features (to save them),
a :class:`~d2slam.slam.features.CachedFeatures` gives them instead of extracting: no image is read then, except the
depth image when there is a keypoint filter (``sequence.depth_image(i)`` when the sequence has it, else the whole
frame); ``extract`` and the fps count the extraction time stored with the features (``d2slam.slam.features``).
Features are stored with the fixed budget ``OrbConfig.n_features``: a run whose budget follows its keypoint filter
(``EngineConfig.refill_filtered``, ``Engine.feature_budget``) takes none (a clear error).
"""

from __future__ import annotations

import time
from concurrent.futures import ThreadPoolExecutor
from typing import Callable

import numpy as np
from tqdm import tqdm

from d2slam.baselines.vocab import resolve_vocabulary
from d2slam.config import DEFAULT, Config
from d2slam.data.base import Trajectory
from d2slam.dynamics import kernels as filter_kernels
from d2slam.errors import D2SlamError
from d2slam.kernel_cache import preload
from d2slam.run.record import EngineRun
from d2slam.slam import depth as depth_kernels, frame as frame_kernels, keyframe_database, lm, matching, orb_vocabulary
from d2slam.slam.engine import STAGES as ENGINE_STAGES, Engine
from d2slam.slam.features import CachedFeatures, FeatureRecorder
from d2slam.slam.orb_vocabulary import vocabulary_ready

STAGES = ("load", "segment") + ENGINE_STAGES

Recorder = Callable[[int, np.ndarray, "np.ndarray | None", object], None]


def ensure_vocabulary(config: Config = DEFAULT) -> None:
    """Make the vocabulary an engine of ``config`` loads ready before it starts: the engine loads a vocabulary file
    and nothing else, so the project's is built here on first use (announced; ``d2slam vocab build``) and any other
    file checked (:func:`d2slam.baselines.vocab.resolve_vocabulary`) unless its bag of words is derived already."""
    path = config.engine.vocabulary or None
    if config.engine.loop_closing and not vocabulary_ready(path):
        resolve_vocabulary(path, build=True, progress=False)


def load_kernels() -> int:
    """The engine's and the filter's compiled kernels loaded from numba's disk cache before a run's clock starts
    (:func:`d2slam.kernel_cache.preload`); returns how many were loaded now."""
    return preload(filter_kernels, depth_kernels, frame_kernels, keyframe_database, lm, matching, orb_vocabulary)


def run_sequence(sequence, config: Config = DEFAULT, keypoint_filter=None,
                 mask_provider: Callable[[int], "np.ndarray | None"] | None = None,
                 recorder: Recorder | None = None, progress: bool | None = None, desc: str | None = None,
                 engine: Engine | None = None, prefetch: bool = True, features=None,
                 frames: int | None = None) -> EngineRun:
    """Run every frame of ``sequence`` (the first ``frames`` when given) through the engine (see module docstring).
    ``recorder(frame index, keypoints (N, 2), beliefs (N,) or None, diagnostics)`` is called after each frame
    (diagnostics: the filter's ``last`` attribute when it has one)."""
    n = len(sequence) if frames is None else min(len(sequence), int(frames))
    if n == 0:
        raise D2SlamError("sequence has no frames", path=getattr(sequence, "root", None))
    if engine is None:
        ensure_vocabulary(config)
        engine = Engine(sequence.camera, config, keypoint_filter)
    cached, recorder_f = _check_features(features, engine, sequence, n)
    load_kernels()
    tally = _Tally(n, mask_provider is not None)
    source = _FrameSource(sequence, n, cached, keypoint_filter is not None, mask_provider, prefetch)
    bar = tqdm(range(n), desc=desc or f"run {getattr(sequence, 'name', '')}", unit="frame",
               disable=None if progress is None else not progress)
    for i in bar:
        frame, masks, load_s, segment_s, upcoming = source.get(i)
        if cached is not None:  # frame is the depth image or None
            res = engine.process(None, frame, i, float(cached.timestamps[i]), masks=masks, features=cached.frame(i))
            tally.stored_extraction(res, float(cached.extract_ms[i]) / 1000.0)
        else:
            res = engine.process(frame.gray, frame.depth, i, frame.timestamp, masks=masks, upcoming=upcoming)
            if recorder_f is not None:
                recorder_f.add(engine.last, res.timings["extract"])
        tally.add(i, res, load_s, segment_s, engine)
        if recorder is not None:
            last = engine.last
            recorder(i, last.kps, last.belief, getattr(keypoint_filter, "last", None))
        if i == 0:
            tally.first_frame_at = time.time()
        if i % 10 == 0:
            bar.set_postfix(tracked=tally.tracked, kfs=tally.keyframes)
    source.close()
    engine.close()
    return tally.run(engine, getattr(sequence, "name", ""))


def _check_features(features, engine: Engine, sequence, n: int):
    """(stored features to read, a recorder of the extracted features to fill): one of them or neither; a clear error
    for anything else, and for features with an engine whose budget follows its filter."""
    cached = features if isinstance(features, CachedFeatures) else None
    recorder_f = features if isinstance(features, FeatureRecorder) else None
    if features is not None and cached is None and recorder_f is None:
        raise D2SlamError(f"features must be a FeatureRecorder or CachedFeatures, not {type(features).__name__}")
    if features is not None and engine.refills:
        raise D2SlamError("stored or recorded features need a fixed extraction budget; with "
                          "EngineConfig.refill_filtered and a keypoint filter each frame's budget depends on the "
                          "filter (run without features, or with refill_filtered=False)")
    if cached is not None:
        cached.check(sequence.timestamps[:n])
    return cached, recorder_f


class _FrameSource:
    """Frame ``i`` and its masks, as ``run_sequence`` asks for them: what is read per frame is the whole frame, the
    depth image only (stored features and a filter), or nothing. Frames and their masks are read one and two ahead
    by a reader thread (PNG decoding releases the GIL), and the engine extracts frame i+1 in its worker while it
    tracks frame i (``Engine.process(upcoming=...)``): results identical to doing it all in order."""

    def __init__(self, sequence, n: int, cached, has_filter: bool, mask_provider, prefetch: bool):
        if cached is None:
            self.reader = sequence.__getitem__
        elif has_filter:
            self.reader = getattr(sequence, "depth_image", None) or (lambda i: sequence[i].depth)
        else:
            self.reader = None
        self.n, self.cached, self.mask_provider = n, cached, mask_provider
        self.pool = ThreadPoolExecutor(max_workers=1) if prefetch and self.reader is not None and n > 1 else None
        self.pending: dict = {}
        self._fetch(0)
        self._fetch(1)

    def _read(self, j: int):
        frame = self.reader(j)
        if self.cached is None:
            _ = frame.gray  # converted once, here in the reader thread (cvtColor releases the GIL)
        if self.mask_provider is None:
            return frame, None, 0.0
        t = time.perf_counter()
        return frame, self.mask_provider(j), time.perf_counter() - t

    def _fetch(self, j: int) -> None:
        if self.pool is not None and j < self.n and j not in self.pending:
            self.pending[j] = self.pool.submit(self._read, j)

    def get(self, i: int):
        """(frame i: the frame, its depth image or None; its masks or None; seconds spent waiting for the images
        (``load``); seconds the mask provider took (``segment``); the next frame's ``(gray, depth, index,
        timestamp)`` for the engine to extract ahead, or None)."""
        t0 = time.perf_counter()
        if self.pool is None:
            frame = self.reader(i) if self.reader is not None else None
            t1 = time.perf_counter()
            masks = self.mask_provider(i) if self.mask_provider is not None else None
            return frame, masks, t1 - t0, time.perf_counter() - t1, None
        frame, masks, segment_s = self.pending.pop(i).result()
        self._fetch(i + 2)
        upcoming = None
        if self.cached is None and i + 1 < self.n:
            nxt = self.pending[i + 1].result()[0]
            upcoming = (nxt.gray, nxt.depth, i + 1, nxt.timestamp)
        return frame, masks, time.perf_counter() - t0, segment_s, upcoming

    def close(self) -> None:
        if self.pool is not None:
            self.pool.shutdown()


class _Tally:
    """The per-stage timings, states and per-frame rows of a run, and the :class:`EngineRun` they make."""

    def __init__(self, n: int, has_masks: bool):
        self.n, self.has_masks = n, has_masks
        self.totals = dict.fromkeys(STAGES, 0.0)
        self.states: list[str] = []
        self.per_frame: list[dict] = []
        self.keyframes = 0
        self.extract_adjust = 0.0  # stored extraction time minus the time the stored read took
        self.first_frame_at = float("nan")  # time.time() when the first frame was done
        self.t_start = time.perf_counter()

    @property
    def tracked(self) -> int:
        return sum(s == "ok" for s in self.states)

    def stored_extraction(self, res, stored_s: float) -> None:
        """Frame features that came stored: their extraction counts with the time it took when they were stored."""
        self.extract_adjust += stored_s - res.timings["extract"]
        res.timings["extract"] = stored_s

    def add(self, i: int, res, load_s: float, segment_s: float, engine: Engine) -> None:
        self.totals["load"] += load_s
        self.totals["segment"] += segment_s
        for k, v in res.timings.items():
            self.totals[k] += v
        self.states.append(res.state)
        self.keyframes += int(res.keyframe)
        self.per_frame.append({"index": i, "state": res.state, "how": res.how, "keypoints": res.n_keypoints,
                               "inliers": res.n_inliers, "keyframe": res.keyframe,
                               "map_points": engine.map.n_points, "keyframes": len(engine.map.good_keyframes())})

    def run(self, engine: Engine, name: str) -> EngineRun:
        n = self.n
        total = time.perf_counter() - self.t_start + self.extract_adjust
        _, ts, poses = engine.trajectory()
        tracked = int(self.tracked)
        stage_ms = {k: 1000.0 * v / n for k, v in self.totals.items() if k != "segment" or self.has_masks}
        lc = engine.loop
        return EngineRun(trajectory=Trajectory(ts, poses, meta={"sequence": name}), frames=n, tracked=tracked,
                         lost=n - tracked, states=self.states, keyframes=len(engine.map.good_keyframes()),
                         map_points=engine.map.n_points, stage_ms=stage_ms, total_s=total,
                         fps=n / total if total > 0 else float("inf"), per_frame=self.per_frame,
                         first_frame_at=self.first_frame_at, loop_closing=lc is not None,
                         loops=[x.to_dict() for x in engine.loops],
                         loop_candidates=list(lc.log) if lc is not None else [],
                         loop_detect_ms=[1000.0 * t for t in lc.detect_s] if lc is not None else [],
                         loop_detect_cpu_ms=[1000.0 * t for t in lc.detect_cpu_s] if lc is not None else [])
