"""Run a sequence through the SLAM engine: one function, a progress bar, per-stage timings, a result object.

    run = run_sequence(open_sequence(path), keypoint_filter=None, mask_provider=None)
    run.trajectory  # tracked frames only (T_world_camera), run.tracked / run.lost, run.fps (d2slam.run.record.EngineRun)

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
from d2slam.errors import D2SlamError
from d2slam.run.record import EngineRun
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
    # What is read per frame: the whole frame, the depth image only (stored features and a filter), or nothing.
    if cached is None:
        reader = sequence.__getitem__
    elif keypoint_filter is not None:
        reader = getattr(sequence, "depth_image", None) or (lambda i: sequence[i].depth)
    else:
        reader = None
    extract_adjust = 0.0  # cached extraction time minus the time the cached read took
    first_frame_at = float("nan")
    totals = dict.fromkeys(STAGES, 0.0)
    states, per_frame = [], []
    keyframes = 0
    t_start = time.perf_counter()
    bar = tqdm(range(n), desc=desc or f"run {getattr(sequence, 'name', '')}", unit="frame",
               disable=None if progress is None else not progress)
    # Frames and their masks are read one and two ahead by a reader thread (PNG decoding releases the GIL), and the
    # engine extracts frame i+1 in its worker while it tracks frame i (``Engine.process(upcoming=...)``): results
    # identical to doing it all in order; ``load`` is the time spent waiting for the images and masks, ``segment`` the
    # mask provider's own time in the reader thread.
    pool = ThreadPoolExecutor(max_workers=1) if prefetch and reader is not None and n > 1 else None
    pending: dict = {}

    def read(j: int):
        frame = reader(j)
        if mask_provider is None:
            return frame, None, 0.0
        t = time.perf_counter()
        return frame, mask_provider(j), time.perf_counter() - t

    def fetch(j: int) -> None:
        if pool is not None and j < n and j not in pending:
            pending[j] = pool.submit(read, j)

    fetch(0)
    fetch(1)
    for i in bar:
        t0 = time.perf_counter()
        upcoming = None
        if pool:
            frame, masks, segment_s = pending.pop(i).result()
            fetch(i + 2)
            if cached is None and i + 1 < n:
                nxt = pending[i + 1].result()[0]
                upcoming = (nxt.gray, nxt.depth, i + 1, nxt.timestamp)
            t1 = time.perf_counter()
        else:
            frame = reader(i) if reader is not None else None
            t1 = time.perf_counter()
            masks = mask_provider(i) if mask_provider is not None else None
            segment_s = time.perf_counter() - t1
        if cached is not None:  # frame is the depth image or None
            res = engine.process(None, frame, i, float(cached.timestamps[i]), masks=masks,
                                 features=cached.frame(i))
            stored = float(cached.extract_ms[i]) / 1000.0
            extract_adjust += stored - res.timings["extract"]
            res.timings["extract"] = stored
        else:
            res = engine.process(frame.gray, frame.depth, i, frame.timestamp, masks=masks, upcoming=upcoming)
            if recorder_f is not None:
                recorder_f.add(engine.last, res.timings["extract"])
        totals["load"] += t1 - t0
        totals["segment"] += segment_s
        for k, v in res.timings.items():
            totals[k] += v
        states.append(res.state)
        keyframes += int(res.keyframe)
        per_frame.append({"index": i, "state": res.state, "how": res.how, "keypoints": res.n_keypoints,
                          "inliers": res.n_inliers, "keyframe": res.keyframe,
                          "map_points": engine.map.n_points, "keyframes": len(engine.map.good_keyframes())})
        if recorder is not None:
            last = engine.last
            recorder(i, last.kps, last.belief, getattr(keypoint_filter, "last", None))
        if i == 0:
            first_frame_at = time.time()
        if i % 10 == 0:
            bar.set_postfix(tracked=sum(s == "ok" for s in states), kfs=keyframes)
    if pool:
        pool.shutdown()
    engine.close()
    total = time.perf_counter() - t_start + extract_adjust
    _, ts, poses = engine.trajectory()
    tracked = int(sum(s == "ok" for s in states))
    stage_ms = {k: 1000.0 * v / n for k, v in totals.items() if k != "segment" or mask_provider is not None}
    lc = engine.loop
    return EngineRun(trajectory=Trajectory(ts, poses, meta={"sequence": getattr(sequence, "name", "")}),
                     frames=n, tracked=tracked, lost=n - tracked, states=states,
                     keyframes=len(engine.map.good_keyframes()), map_points=engine.map.n_points, stage_ms=stage_ms,
                     total_s=total, fps=n / total if total > 0 else float("inf"), per_frame=per_frame,
                     first_frame_at=first_frame_at,
                     loop_closing=lc is not None, loops=[x.to_dict() for x in engine.loops],
                     loop_candidates=list(lc.log) if lc is not None else [],
                     loop_detect_ms=[1000.0 * t for t in lc.detect_s] if lc is not None else [],
                     loop_detect_cpu_ms=[1000.0 * t for t in lc.detect_cpu_s] if lc is not None else [])
