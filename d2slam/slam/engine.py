"""The ORB-SLAM3-style RGB-D engine, one frame at a time: extraction, the keypoint-filter hook, tracking
(``tracking.py``, with ``relocalisation.py``), and for a new keyframe local mapping (``local_mapping.py``) and loop
closing (``loop_closing.py``, with the keyframe database of ``keyframe_database.py``, which relocalisation also
uses; ``EngineConfig.loop_closing``), run synchronously for determinism (an online run may solve local BA beside
tracking, written back between frames: ``Engine(background=...)``). The engine knows nothing of dynamics except
the hook (``hook.py``)."""

from __future__ import annotations

from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field

import cv2
import numpy as np

from d2slam.data.base import Camera
from d2slam.errors import D2SlamError
from d2slam.slam.config import SlamConfig
from d2slam.slam.frame import Frame, OrbExtractor
from d2slam.slam.hook import FilterHook, FilterInput, HookFrame, KeypointFilter, update_point_beliefs
from d2slam.slam.local_mapping import LocalMapper
from d2slam.slam.loop_closing import LoopCloser
from d2slam.slam.map import KeyFrame, Map
from d2slam.slam.orb_vocabulary import load_vocabulary
from d2slam.slam.projection import Projector, inv
from d2slam.slam.timing import StageTimer
from d2slam.slam.tracking import LOST, NOT_INITIALIZED, OK, Tracker

STAGES = ("extract", "filter", "track", "local_ba", "loop")


@dataclass
class TrackResult:
    index: int
    timestamp: float
    state: str  # "ok" | "lost" | "not_initialized" (the last two are lost frames: no pose)
    how: str  # "init" | "motion" | "reference" | "relocalisation" | ""
    n_keypoints: int
    n_inliers: int
    keyframe: bool
    timings: dict = field(default_factory=dict)  # seconds per stage (STAGES)
    mapped: bool = False  # a local BA solved beside tracking was written back before this frame

    @property
    def tracked(self) -> bool:
        return self.state == OK


def refills(config: SlamConfig, keypoint_filter: KeypointFilter | None) -> bool:
    """Whether a run's extraction budget depends on its filter's output (``EngineConfig.refill_filtered`` and a
    filter): such a run extracts every frame itself and cannot use stored features (see ``Engine.feature_budget``)."""
    return bool(config.engine.refill_filtered and keypoint_filter is not None)


class Engine:
    def __init__(self, camera: Camera, config: SlamConfig = SlamConfig(),
                 keypoint_filter: KeypointFilter | None = None, background=None):
        """``background``: solves each keyframe's local BA beside tracking (``local_mapping.MappingThread``, or an
        online run's replay of one), its solution written back at the start of the first frame after it is done, or
        before the next keyframe; None (offline): in the frame after the keyframe, in order."""
        cv2.setNumThreads(int(config.engine.cv_threads))
        self.camera = camera
        self.config = config
        self.cfg = config.engine
        self.orb = config.orb
        self.filter = keypoint_filter
        self.proj = Projector(camera, config)
        self.extractor = OrbExtractor(config.orb, config.engine, camera)
        self.hook = FilterHook(keypoint_filter, self.proj, config) if keypoint_filter is not None else None
        self.background = background
        self.vocabulary = load_vocabulary(self.cfg.vocabulary or None) if self.cfg.loop_closing else None
        self._worker: ThreadPoolExecutor | None = None  # extracts the upcoming frame while this one is tracked
        self._upcoming: tuple[int, Future] | None = None
        self.reset()

    def reset(self) -> None:
        self._drop_upcoming()
        self.map = Map()
        self.tracker = Tracker(self.map, self.proj, self.config)
        self.mapper = LocalMapper(self.map, self.proj, self.config, self.vocabulary, self.background)
        self.loop = None
        if self.vocabulary is not None:
            self.loop = LoopCloser(self.map, self.proj, self.config, self.vocabulary, self.mapper)
            self.tracker.keyframe_db = self.loop.db
        self.previous: HookFrame | None = None  # the last processed frame (tracked or not) and its images
        self.frame_refs: dict[int, tuple[int, np.ndarray]] = {}  # frame index -> (ref keyframe id, T_c_ref)
        self.timestamps: dict[int, float] = {}
        if self.hook is not None:
            self.hook.reset()

    @property
    def last(self) -> Frame | None:
        """The last processed frame (tracked or not)."""
        return self.previous.frame if self.previous is not None else None

    @property
    def last_filter_input(self) -> FilterInput | None:
        return self.hook.last_input if self.hook is not None else None

    # ================================================================== per frame
    def process(self, gray: np.ndarray | None, depth: np.ndarray | None, index: int, timestamp: float,
                masks: np.ndarray | None = None, features: Frame | None = None, upcoming=None) -> TrackResult:
        """Track one frame. ``features``: the frame's features extracted earlier by an extractor with this engine's
        settings (``d2slam.slam.features``); then no image is needed, except the depth by a keypoint filter.

        ``upcoming``: the next frame's ``(gray, depth, index, timestamp)``. Its extraction starts in a worker thread
        as soon as this frame's filter has run (the filter decides its budget, ``feature_budget``) and overlaps this
        frame's tracking and mapping; the next call takes it if its index matches. The result is the same as
        extracting in order (the extractor is a function of the images and the budget). The ``extract`` timing is
        then the extraction's own time in the worker, which overlaps the other stages."""
        gray = self._gray(gray)
        self._check_input(gray, depth, index, features)
        timer = StageTimer(*STAGES)
        tracker = self.tracker
        with timer("local_ba"):
            done, culled = self.mapper.collect(wait=False)
            self._replace_culled_reference(done, culled)
        if features is not None:
            frame = features
        elif self._upcoming is not None and self._upcoming[0] == index:
            frame, timer.seconds["extract"] = self._upcoming[1].result()
            self._upcoming = None
        else:
            self._drop_upcoming()
            with timer("extract"):
                frame = self.extractor(gray, depth, index, timestamp, self.feature_budget())
        current = HookFrame(frame, gray, depth)
        with timer("filter"):
            if self.hook is not None:
                prev = self.previous
                tracked = prev is not None and prev.frame is tracker.last_tracked
                self.hook(current, masks, prev, self.map, tracker.motion(frame.index) if tracked else None)
        if upcoming is not None and features is None:
            self._extract_upcoming(frame, *upcoming)
        with timer("track"):
            ok, how = tracker.track(frame)
            if ok:
                update_point_beliefs(self.map, frame, self.cfg.mappoint_belief_threshold)
        keyframe = ok and how != "init" and tracker.need_new_keyframe(frame)
        with timer("local_ba"):
            if keyframe:
                self._replace_culled_reference(*self.mapper.collect(wait=True))
                kf = tracker.create_keyframe(frame)
                self._replace_culled_reference(kf, self.mapper.insert(kf))
            else:
                self._replace_culled_reference(*self.mapper.idle())
        keyframe = keyframe or (ok and how == "init")
        with timer("loop"):
            if keyframe and self.loop is not None:
                self._close_loops(frame, self.map.keyframes[-1])
        with timer("track"):
            tracker.finish(frame, ok)
            if ok:
                self.frame_refs[index] = (frame.ref_kf, frame.Tcr)
                self.timestamps[index] = timestamp
            self.previous = current
        state = OK if ok else (NOT_INITIALIZED if tracker.state == NOT_INITIALIZED else LOST)
        n_in = int(((frame.mp >= 0) & ~frame.outlier).sum()) if ok else 0
        return TrackResult(index, timestamp, state, how, frame.n, n_in, keyframe, timer.seconds,
                           mapped=done is not None)

    @staticmethod
    def _gray(image: np.ndarray | None) -> np.ndarray | None:
        return cv2.cvtColor(image, cv2.COLOR_RGB2GRAY) if image is not None and image.ndim == 3 else image

    def _extract_upcoming(self, frame: Frame, gray, depth, index: int, timestamp: float) -> None:
        """Start extracting the next frame with the budget this frame's filter output gives."""
        budget = self.feature_budget(frame)
        gray = self._gray(gray)
        if self._worker is None:
            self._worker = ThreadPoolExecutor(max_workers=1, thread_name_prefix="d2slam-extract")

        def job():
            timer = StageTimer("extract")
            with timer("extract"):
                out = self.extractor(gray, depth, index, timestamp, budget)
            return out, timer.seconds["extract"]

        self._upcoming = (int(index), self._worker.submit(job))

    def _drop_upcoming(self) -> None:
        if self._upcoming is not None:
            self._upcoming[1].result()  # never two extractions at once (the extractor's ORB objects are shared)
            self._upcoming = None

    def close(self) -> None:
        """Stop the extraction worker (an engine that is garbage-collected stops it too) and the background's."""
        self._drop_upcoming()
        if self.background is not None:
            self.background.close()
        if self._worker is not None:
            self._worker.shutdown()
            self._worker = None

    def _close_loops(self, frame: Frame, kf: KeyFrame) -> None:
        """The new keyframe goes to the loop closer; after a correction the frame and the last tracked frame follow
        their reference keyframes (as ORB-SLAM's ``UpdateLastFrame``), so the motion model carries on in the
        corrected map."""
        tracker = self.tracker
        follow = []
        for f in (frame, tracker.last_tracked):
            if f is None or f.Tcw is None:
                continue
            if f is frame:
                ref = tracker.ref_kf
                follow.append((f, ref, f.Tcw @ inv(ref.Tcw)))
            elif f.index in self.frame_refs:
                rid, Tcr = self.frame_refs[f.index]
                follow.append((f, self.map.keyframes[rid], Tcr))
        if self.loop.insert(kf) is not None:
            for f, ref, Tcr in follow:
                f.Tcw = Tcr @ ref.Tcw

    @property
    def loops(self) -> list:
        """The loops closed so far (``loop_closing.Loop``; empty without loop closing)."""
        return list(self.loop.loops) if self.loop is not None else []

    def _replace_culled_reference(self, kf, culled: list[int]) -> None:
        """A reference keyframe that local mapping culled is replaced by ``kf``, the keyframe that made it redundant
        (ORB-SLAM KeyFrameCulling)."""
        ref = self.tracker.ref_kf
        if kf is not None and ref is not None and ref.id in culled:
            self.tracker.ref_kf = kf

    def _check_input(self, gray, depth, index: int, features) -> None:
        if features is None and (gray is None or depth is None):
            raise D2SlamError(f"frame {index}: the images are needed (no precomputed features)")
        if features is not None and self.refills:
            raise D2SlamError(f"frame {index}: stored features have the fixed budget of {self.orb.n_features} "
                              "keypoints; with refill_filtered and a keypoint filter the engine extracts every frame "
                              "itself (EngineConfig.refill_filtered=False to use stored features)")
        if self.filter is not None and depth is None:
            raise D2SlamError(f"frame {index}: the keypoint filter needs the depth image")
        if gray is not None and depth is not None and depth.shape != gray.shape:
            raise D2SlamError(f"frame {index}: depth {depth.shape} and image {gray.shape} differ in size")

    @property
    def refills(self) -> bool:
        """Whether each frame's extraction budget depends on the filter's output (``refills`` of this engine)."""
        return refills(self.config, self.filter)

    def feature_budget(self, last: Frame | None = None) -> int:
        """Keypoints to extract from the next frame: ``n_features``, plus (``refills``) as many as the hook flagged in
        the last frame, at most ``refill_max`` x ``n_features``. The flagged keypoints take no part in tracking or
        mapping, so the frame keeps about ``n_features`` usable ones, like a run without people (the static twin),
        or DynaSLAM, which extracts outside its masks (measured: ``docs/deviations.md``)."""
        n = self.orb.n_features
        last = self.last if last is None else last
        if not self.refills or last is None or last.belief is None:
            return n
        return int(min(n + int(last.dynamic.sum()), self.cfg.refill_max * n))

    # ================================================================== results
    def trajectory(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(frame indices, timestamps, poses T_world_camera) of the tracked frames, each frame's pose taken relative
        to its reference keyframe's final (bundle-adjusted) pose, as ORB-SLAM's SaveTrajectoryTUM. Pending local
        mapping runs first (as ORB-SLAM3 empties its queue before saving): call it once the frames are done."""
        self._replace_culled_reference(*self.mapper.collect(wait=True))
        self._replace_culled_reference(*self.mapper.idle(now=True))
        idx = np.array(sorted(self.frame_refs), dtype=np.int64)
        poses = np.zeros((len(idx), 4, 4))
        for i, f in enumerate(idx):
            kf_id, Tcr = self.frame_refs[int(f)]
            poses[i] = inv(Tcr @ self.map.keyframes[kf_id].Tcw)
        ts = np.array([self.timestamps[int(f)] for f in idx])
        return idx, ts, poses
