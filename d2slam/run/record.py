"""What a run gives: :class:`RunRecord` for every method (our engine's, the real ORB-SLAM3's, ORB-SLAM3's on masked
frames), the one shape that ``d2slam run`` prints and writes and the study turns into its rows and tables; and each
method's own account of a run, which a record carries: :class:`EngineRun`, the engine's
(``d2slam.run.sequence.run_sequence``), and :class:`Orbslam3Run`, the real ORB-SLAM3's.

A run that tracked less than ``EvalConfig.min_tracked_share`` of its frames is a fragment
(:mod:`d2slam.eval.fragment`): :attr:`RunRecord.fragment` says so.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from d2slam.data.base import Trajectory
from d2slam.eval.config import EvalConfig
from d2slam.eval.fragment import is_fragment, tracked_share
from d2slam.eval.trajectory import Evaluation

# The exit status of `d2slam run` for a fragment (a run that tracked less than EvalConfig.min_tracked_share of its
# frames); 2 is bad input (d2slam.cli), 1 ORB-SLAM3 losing track.
EXIT_FRAGMENT = 3


@dataclass
class EngineRun:
    """A sequence run through the engine (``d2slam.run.sequence.run_sequence``)."""

    trajectory: Trajectory  # tracked frames only
    frames: int
    tracked: int
    lost: int
    states: list[str]  # per frame: "ok" | "lost" | "not_initialized"
    keyframes: int
    map_points: int
    stage_ms: dict[str, float]  # mean milliseconds per frame and stage
    total_s: float
    fps: float
    per_frame: list[dict] = field(default_factory=list)
    first_frame_at: float = float("nan")  # time.time() when the first frame was done (cold-start measurements)
    # Loop closing (``EngineConfig.loop_closing``): the loops closed (``Loop.to_dict``), every place-recognition
    # candidate (``Candidate``), the detection time of each keyframe (ms, wall and CPU) and each correction's (s).
    loop_closing: bool = False
    loops: list[dict] = field(default_factory=list)
    loop_candidates: list = field(default_factory=list)
    loop_detect_ms: list[float] = field(default_factory=list)
    loop_detect_cpu_ms: list[float] = field(default_factory=list)  # the same in CPU time

    @property
    def ms_per_frame(self) -> float:
        return 1000.0 * self.total_s / max(self.frames, 1)

    def summary(self) -> dict:
        return {"frames": self.frames, "tracked": self.tracked, "lost": self.lost, "keyframes": self.keyframes,
                "map_points": self.map_points, "fps": round(self.fps, 2),
                "stage_ms": {k: round(v, 3) for k, v in self.stage_ms.items()}}


@dataclass
class Orbslam3Run:
    """The real ORB-SLAM3's account of a run (its run JSON, ``report``: ``d2slam.baselines.orbslam3``), as a
    :class:`RunRecord` reads it: the median figures over its repeats; no keyframe or map-point counts, no stages."""

    trajectory: Trajectory | None  # the last repeat's tracked frames, read back (None: it wrote none)
    frames: int | None
    tracked: int | None
    lost: int | None
    fps: float | None
    ms_per_frame: float | None
    report: dict
    keyframes: int | None = None
    map_points: int | None = None
    stage_ms: dict[str, float] = field(default_factory=dict)
    loop_closing: bool = True  # ORB-SLAM3 always closes loops


@dataclass
class RunRecord:
    """One run of a method on a sequence, evaluated against its ground truth when it has one.

    ``run`` is the method's own account of it: the engine's (:class:`EngineRun`) or the real ORB-SLAM3's
    (:class:`Orbslam3Run`); the record reads its figures (frames, tracked, fps, ...) there. ``status`` and ``error``
    say how the run ended, as the study's ``runs.csv`` records it: for the engine's methods ``ok`` (ATE and RPE),
    ``partial`` (the ATE alone: too short for a 1-second RPE pair) or ``unevaluated``; for ORB-SLAM3 its own outcome
    (``ok``, ``lost``, ``reset``, ``failed``, ``crashed``, ``timeout``; ``unevaluated`` when it tracked but gave no
    metrics). ORB-SLAM3 runs ``repeats`` times: its figures are the medians, ``ate_range`` the ATE's (min, max) over
    the repeats."""

    method: str
    sequence: str  # the sequence's name
    run: EngineRun | Orbslam3Run
    config_hash: str
    status: str
    error: str  # why the status is not ``ok`` ("" when it is)
    evaluation: Evaluation | None  # None: the sequence has no ground truth, or the run gave no trajectory
    masks: str | None = None  # the mask kind read (None: none)
    masks_origin: str | None = None  # where they came from (``d2slam.segmentation.masks_origin``)
    repeats: int = 1
    ate_range: tuple[float, float] | None = None
    keypoints: dict | None = None  # classification against the synthetic truth (``d2slam.eval.keypoints``)
    loops: dict | None = None  # ``d2slam.eval.loops.loop_summary`` (the engine's methods)
    min_tracked_share: float = EvalConfig().min_tracked_share  # the run's config's (``EvalConfig``)

    trajectory = property(lambda self: self.run.trajectory, doc="T_world_camera of the tracked frames")
    frames = property(lambda self: self.run.frames, doc="frames run")
    tracked = property(lambda self: self.run.tracked)
    lost = property(lambda self: self.run.lost)
    fps = property(lambda self: self.run.fps)
    ms_per_frame = property(lambda self: self.run.ms_per_frame)
    keyframes = property(lambda self: self.run.keyframes)
    map_points = property(lambda self: self.run.map_points)
    stage_ms = property(lambda self: self.run.stage_ms, doc="the engine's stages (``d2slam.run.sequence.STAGES``)")
    loop_closing = property(lambda self: self.run.loop_closing)

    @property
    def engine(self) -> EngineRun | None:
        """The engine's own account (the engine's methods), else None."""
        return self.run if isinstance(self.run, EngineRun) else None

    @property
    def orbslam3(self) -> dict | None:
        """ORB-SLAM3's run JSON (``d2slam.baselines.orbslam3``), else None."""
        return self.run.report if isinstance(self.run, Orbslam3Run) else None

    @property
    def tracked_share(self) -> float:
        """``tracked / frames`` (NaN when unknown: a run that failed before its frames)."""
        return tracked_share(self.tracked, self.frames)

    @property
    def fragment(self) -> bool:
        """The run tracked less than ``min_tracked_share`` of its frames (:func:`is_fragment`): its ATE and RPE are
        over the tracked part only."""
        return is_fragment(self.tracked_share, self.min_tracked_share)
