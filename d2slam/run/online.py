"""Online runs: the engine and the segmenter at the sensor's rate, as on a robot, with late frames dropped.

Offline (``d2slam.run.sequence.run_sequence``) every frame is segmented before it is tracked and nothing is dropped: the
paper's protocol. Online:

- frames *arrive* at their timestamps (or at ``OnlineConfig.rate_hz``), decoded, as a camera driver delivers them;
- the segmenter runs in its own thread (:class:`MaskThread`) on the newest frame that has arrived when it is free;
- the tracker takes the newest frame that has arrived when it is free and never waits for a mask. A frame that
  arrives while the tracker is busy waits in a one-frame slot, where the next arrival replaces it: every frame but
  the newest is dropped, as a camera with a one-frame buffer (a ROS subscriber with ``queue_size=1``) drops them;
- a frame reads the newest mask the segmenter has finished, of an earlier frame at most
  ``OnlineConfig.mask_max_age_s`` older (``masks="latest"``; NGD-SLAM carries its masks forward the same way), with
  ``mask_motion`` (ours, off) each person moved on by its motion between the segmenter's two newest results
  (:func:`extrapolate_masks`), or none (``masks="off"``). Without a mask eq 7 has no mask area: matched keypoints take P_g, unmatched ones 0.5, and
  eq 8 carries each keypoint's belief through its match and its map point.

What happens depends on timing, so an online run is not reproducible. Its :class:`Schedule` (which frames were
tracked, with which frame's mask, and the masks themselves) is, and :func:`replay` runs the same schedule again
byte for byte (``d2slam run --deterministic LOG.npz``): the engine is a function of its frames and masks.

:class:`OnlineSLAM` is the Python API for a live camera: ``slam.track(frame)`` per frame, as it comes.
"""

from __future__ import annotations

import json
import os
import sys
import threading
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import cv2
import numpy as np
from tqdm import tqdm

from d2slam.config import DEFAULT, Config
from d2slam.data.base import Trajectory
from d2slam.data.live import arrival_times, newest_arrived
from d2slam.errors import D2SlamError
from d2slam.eval.fragment import fragment_fields
from d2slam.eval.trajectory import evaluate_run
from d2slam.outputs import staged_file
from d2slam.ranges import overridden
from d2slam.run import warmup
from d2slam.run.methods import get_method
from d2slam.segmentation import get_segmenter, masks_for, stack_masks
from d2slam.slam.engine import Engine
from d2slam.slam.local_mapping import MappingThread

SCHEDULE_VERSION = 2


@dataclass
class Schedule:
    """What an online run did, enough to run it again (:func:`replay`) and to judge it. Times in seconds from the
    first frame's arrival. ``processed[j]`` was tracked with the mask of frame ``mask_of[j]`` (-1: none), taken at
    ``start_s[j]`` and done at ``done_s[j]``; the segmenter segmented ``segmented[m]`` from ``seg_start_s[m]`` to
    ``seg_done_s[m]``; ``masks[i]`` are the person masks (n, H, W) bool frame ``i`` read (those of frame
    ``mask_of[j]``, moved on: :func:`pick_mask`), for every processed frame that read some; ``mapped`` are the
    frames before which a local BA solved beside tracking was written back (``OnlineConfig.mapping_thread``)."""

    frames: int
    rate_hz: float  # 0: the frames' timestamps
    arrival_s: np.ndarray
    processed: list[int] = field(default_factory=list)
    mask_of: list[int] = field(default_factory=list)
    start_s: list[float] = field(default_factory=list)
    done_s: list[float] = field(default_factory=list)
    segmented: list[int] = field(default_factory=list)
    seg_start_s: list[float] = field(default_factory=list)
    seg_done_s: list[float] = field(default_factory=list)
    masks: dict[int, np.ndarray] = field(default_factory=dict)
    mapped: list[int] = field(default_factory=list)
    meta: dict = field(default_factory=dict)

    @property
    def dropped(self) -> int:
        return self.frames - len(self.processed)

    @property
    def lag_ms(self) -> np.ndarray:
        """Each tracked frame's lag: from its arrival to its pose (ms)."""
        idx = np.asarray(self.processed, dtype=np.int64)
        return 1000.0 * (np.asarray(self.done_s, dtype=np.float64) - self.arrival_s[idx])

    def summary(self) -> dict:
        """Frames processed and dropped, the segmenter's frames per second, the lag (median, 95th percentile)."""
        lag = self.lag_ms
        wall = max(self.done_s[-1] if self.done_s else 0.0, float(self.arrival_s[-1]) if self.frames else 0.0)
        with_mask = int(sum(k >= 0 for k in self.mask_of))
        return {"rate_hz": self.rate_hz, "frames": self.frames, "processed": len(self.processed),
                "dropped": self.dropped, "processed_share": round(len(self.processed) / max(self.frames, 1), 4),
                "segmented": len(self.segmented),
                "segmenter_fps": round(len(self.segmented) / wall, 2) if wall > 0 else None,
                "with_mask": with_mask,
                "mask_age_ms_median": _median_ms(self._mask_ages()),
                "lag_ms_median": round(float(np.median(lag)), 2) if len(lag) else None,
                "lag_ms_p95": round(float(np.percentile(lag, 95)), 2) if len(lag) else None}

    def _mask_ages(self) -> np.ndarray:
        """Seconds between the arrival of each tracked frame that read a mask and its mask's frame."""
        pairs = [(i, k) for i, k in zip(self.processed, self.mask_of) if k >= 0]
        return np.array([self.arrival_s[i] - self.arrival_s[k] for i, k in pairs], dtype=np.float64)

    # ------------------------------------------------------------------------------------------------ file
    def save(self, path: str | Path) -> None:
        """One ``.npz`` (written whole or not at all): the schedule's arrays, its masks bit-packed, ``meta``."""
        arrays = {"arrival_s": np.asarray(self.arrival_s, np.float64),
                  "processed": np.asarray(self.processed, np.int64), "mask_of": np.asarray(self.mask_of, np.int64),
                  "start_s": np.asarray(self.start_s, np.float64), "done_s": np.asarray(self.done_s, np.float64),
                  "segmented": np.asarray(self.segmented, np.int64),
                  "seg_start_s": np.asarray(self.seg_start_s, np.float64),
                  "seg_done_s": np.asarray(self.seg_done_s, np.float64),
                  "mapped": np.asarray(self.mapped, np.int64)}
        for k, m in self.masks.items():
            arrays[f"mask_{k}"] = np.packbits(np.asarray(m, bool), axis=None)
            arrays[f"mask_{k}_shape"] = np.asarray(np.shape(m), np.int64)
        head = {"version": SCHEDULE_VERSION, "frames": self.frames, "rate_hz": self.rate_hz, "meta": self.meta}
        arrays["head"] = np.frombuffer(json.dumps(head, sort_keys=True).encode(), dtype=np.uint8)
        with staged_file(path) as tmp:
            with open(tmp, "wb") as f:
                np.savez_compressed(f, **arrays)

    @classmethod
    def load(cls, path: str | Path) -> "Schedule":
        """Read a schedule :meth:`save` wrote; anything else is one clear error."""
        try:
            with np.load(Path(path).expanduser(), allow_pickle=False) as z:
                data = {k: z[k] for k in z.files}
            head = json.loads(bytes(data.pop("head")).decode())
        except FileNotFoundError:
            raise D2SlamError("no such online schedule", path=path) from None
        except Exception as exc:  # a damaged or foreign file: zipfile, json and numpy raise their own types
            raise D2SlamError(f"not an online schedule (d2slam run --online --online-log): "
                              f"{type(exc).__name__}", path=path) from None
        if head.get("version") != SCHEDULE_VERSION:
            raise D2SlamError(f"online schedule version {head.get('version')}, expected {SCHEDULE_VERSION}",
                              path=path)
        masks = {}
        for key in [k for k in data if k.startswith("mask_") and not k.endswith("_shape") and k != "mask_of"]:
            shape = tuple(int(s) for s in data[f"{key}_shape"])
            masks[int(key[5:])] = np.unpackbits(data[key], count=int(np.prod(shape))).astype(bool).reshape(shape)
        s = cls(frames=int(head["frames"]), rate_hz=float(head["rate_hz"]), arrival_s=data["arrival_s"],
                processed=data["processed"].tolist(), mask_of=data["mask_of"].tolist(),
                start_s=data["start_s"].tolist(), done_s=data["done_s"].tolist(),
                segmented=data["segmented"].tolist(), seg_start_s=data["seg_start_s"].tolist(),
                seg_done_s=data["seg_done_s"].tolist(), masks=masks, mapped=data["mapped"].tolist(),
                meta=head.get("meta", {}))
        missing = sorted({i for i, k in zip(s.processed, s.mask_of) if k >= 0} - set(masks))
        if missing or len(s.processed) != len(s.mask_of):
            raise D2SlamError(f"online schedule is inconsistent (masks missing for frames {missing[:5]})", path=path)
        return s


def _median_ms(seconds: np.ndarray):
    return round(1000.0 * float(np.median(seconds)), 2) if len(seconds) else None


class MaskThread:
    """The segmenter in its own thread. ``source()`` gives the newest frame not yet segmented, ``(index, rgb)``, or
    the seconds until the next frame arrives, or None when that is not known (then the thread waits ``idle_s``, or
    until :meth:`wake`); each finished mask replaces the one before (``latest``). It never polls faster: a thread
    that wakes often takes the interpreter's lock from the tracker."""

    def __init__(self, segmenter, source, shape: tuple[int, int], clock, idle_s: float = 0.1, nice: int = 0):
        self._segmenter, self._source, self._shape, self._clock = segmenter, source, shape, clock
        self._nice = nice
        self._stack, self._idle = stack_masks, idle_s
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._wakeup = threading.Event()
        self._latest: tuple | None = None  # (frame, masks, previous frame, its masks) of the two newest results
        self.log: list[tuple[int, float, float]] = []  # (frame, start, done)
        self.error: BaseException | None = None
        self._thread = threading.Thread(target=self._loop, name="d2slam-segment", daemon=True)
        self._thread.start()

    def _loop(self) -> None:
        yield_cpu(self._nice)
        try:
            while not self._stop.is_set():
                item = self._source()
                if item is None or isinstance(item, float):  # nothing new: wait (until the next arrival, if known)
                    self._wakeup.wait(self._idle if item is None else max(item, 0.0005))
                    self._wakeup.clear()
                    continue
                k, rgb = item
                t0 = self._clock()
                masks = self._stack(self._segmenter(rgb), self._shape)
                t1 = self._clock()
                with self._lock:
                    prev = self._latest[:2] if self._latest is not None else (-1, None)
                    self._latest = (int(k), masks, *prev)
                    self.log.append((int(k), t0, t1))
        except BaseException as exc:  # reported by close(): a thread's exception is otherwise lost
            self.error = exc

    def wake(self) -> None:
        """A frame was offered: stop waiting (the live API calls it)."""
        self._wakeup.set()

    def latest(self) -> tuple | None:
        """``(frame, masks, previous frame, its masks)`` of the two newest results (-1, None: no previous), or None."""
        with self._lock:
            return self._latest

    def close(self) -> None:
        self._stop.set()
        self._wakeup.set()
        self._thread.join()
        if self.error is not None:
            if isinstance(self.error, D2SlamError):
                raise self.error
            raise D2SlamError(f"the segmenter's thread failed: {type(self.error).__name__}: {self.error}")


def yield_cpu(nice: int) -> None:
    """The calling thread's niceness raised by ``nice`` (Linux, where a thread has its own; elsewhere, or where the
    system refuses, nothing changes): the scheduler then gives a core to the tracker first."""
    if nice <= 0 or not sys.platform.startswith("linux"):
        return
    tid = threading.get_native_id()
    try:
        os.setpriority(os.PRIO_PROCESS, tid, os.getpriority(os.PRIO_PROCESS, tid) + int(nice))
    except OSError:
        pass


def online_segmenter(config: Config):
    """The real segmenter with the online thread count (``OnlineConfig.segmenter_threads``), as ``rgb -> persons``."""
    seg_cfg = overridden(config.segmentation, {"intra_op_threads": int(config.online.segmenter_threads)})
    seg = get_segmenter("onnx", config=seg_cfg)
    return seg.segment


def pick_mask(latest, index: int, arrival_s: np.ndarray, config: Config):
    """The masks frame ``index`` reads online, and the frame they were segmented on (``(-1, None)``: none).
    ``latest``: :meth:`MaskThread.latest`, or None. With ``OnlineConfig.masks`` "latest": the newest masks, of a frame
    not after ``index`` and at most ``mask_max_age_s`` older, each person moved on by its motion between the two
    newest results (:func:`extrapolate_masks`, with ``mask_motion``)."""
    if latest is None or config.online.masks == "off":
        return -1, None
    k, masks, kp, prev = latest
    if k > index or arrival_s[index] - arrival_s[k] > config.online.mask_max_age_s:
        return -1, None
    if config.online.mask_motion and kp >= 0 and index > k and len(masks):
        masks = extrapolate_masks(masks, prev, (arrival_s[index] - arrival_s[k]) / (arrival_s[k] - arrival_s[kp]),
                                  config.online.mask_match_px)
    return k, masks


def _centroids(masks: np.ndarray) -> np.ndarray:
    """(n, 2) pixel centroids (u, v) of (n, H, W) masks (NaN for an empty one)."""
    out = np.full((len(masks), 2), np.nan)
    for j, m in enumerate(masks):
        v, u = np.nonzero(m)
        if len(u):
            out[j] = u.mean(), v.mean()
    return out


def extrapolate_masks(masks: np.ndarray, prev: np.ndarray, ratio: float, match_px: float) -> np.ndarray:
    """Each person of ``masks`` moved on by ``ratio`` times its centroid's motion since ``prev`` (the segmenter's
    previous result), matched to the previous person nearest its centroid within ``match_px``; a person with no
    match stays where it was. Ours: a mask of an earlier frame lags its person by the segmenter's latency, and the
    motion in the image (the person's and the camera's) carries on over so short a time."""
    if prev is None or not len(prev) or ratio <= 0:
        return masks
    c, cp = _centroids(masks), _centroids(prev)
    out = masks.copy()
    h, w = masks.shape[1:]
    for j in range(len(masks)):
        if not np.isfinite(c[j, 0]):
            continue
        d = np.hypot(*(cp - c[j]).T)
        d[~np.isfinite(d)] = np.inf
        q = int(np.argmin(d))
        if d[q] > match_px:
            continue
        out[j] = _shifted(masks[j], *(ratio * (c[j] - cp[q])))
    return out


def _shifted(mask: np.ndarray, du: float, dv: float) -> np.ndarray:
    """(H, W) bool ``mask`` moved by (du, dv) pixels (nearest pixel; what moves out of the image is lost)."""
    h, w = mask.shape
    shift = np.float32([[1, 0, du], [0, 1, dv]])
    return cv2.warpAffine(mask.astype(np.uint8), shift, (w, h), flags=cv2.INTER_NEAREST) > 0


def track_back(history: list, k: int) -> tuple[np.ndarray, np.ndarray] | None:
    """Where the newest frame's keypoints were at frame ``k``: ``history`` holds ``(frame index, keypoint pixels
    (N, 2), matches (K, 2) to the frame before it in the list)`` of the frames processed in order, the newest last.
    Returns (pixels now (M, 2), pixels at frame ``k`` (M, 2)) of the keypoints followed back through every match to
    ``k``, or None when the list does not reach back to ``k``."""
    idx = np.arange(len(history[-1][1]))
    for j in range(len(history) - 1, 0, -1):
        f, px, m = history[j]
        if f <= k:
            break
        back = np.full(len(px), -1, dtype=np.int64)
        if len(m):
            back[m[:, 0]] = m[:, 1]
        idx = np.where(idx >= 0, back[np.maximum(idx, 0)], -1)
        if history[j - 1][0] == k:
            keep = idx >= 0
            return history[-1][1][keep], history[j - 1][1][idx[keep]]
    return None


def moved_by_tracks(masks: np.ndarray, now: np.ndarray, then: np.ndarray, min_tracks: int) -> np.ndarray:
    """Each person of ``masks`` (of an earlier frame) moved by the median image motion ``now - then`` of the
    keypoints that lay inside it then (:func:`track_back`); one with fewer than ``min_tracks`` of them stays. Ours
    (``OnlineConfig.mask_tracks``): the motion of a person's own keypoints since the mask's frame carries both the
    person's and the camera's."""
    out = masks.copy()
    h, w = masks.shape[1:]
    u = np.clip(np.rint(then[:, 0]).astype(np.int64), 0, w - 1)
    v = np.clip(np.rint(then[:, 1]).astype(np.int64), 0, h - 1)
    for j in range(len(masks)):
        inside = masks[j][v, u]
        if int(inside.sum()) >= min_tracks:
            out[j] = _shifted(masks[j], *np.median(now[inside] - then[inside], axis=0))
    return out


class TrackedMasks:
    """A keypoint filter whose late masks are moved to the current frame by their people's keypoint tracks
    (:func:`moved_by_tracks`) before the filter reads them. ``mask_frame``: the frame the next call's masks were
    segmented on (set before each ``Engine.process``; -1: none). Keeps the last ``depth`` frames' keypoints and
    matches (the oldest mask a frame may read, ``mask_max_age_s``, at the rate)."""

    def __init__(self, inner, min_tracks: int, depth: int):
        self.inner, self.min_tracks, self.depth = inner, int(min_tracks), int(depth)
        self.mask_frame = -1
        self.history: list = []

    def __getattr__(self, name):
        return getattr(self.inner, name)

    def reset(self) -> None:
        self.history = []
        self.inner.reset()

    def __call__(self, inp):
        px = np.asarray(inp.pixels()[0], dtype=np.float64).reshape(-1, 2)
        if self.history and len(self.history[-1][1]) != len(inp.prev_kps):  # not the frame before: start again
            self.history = []
        self.history = (self.history + [(inp.frame_index, px, np.asarray(inp.matches, np.int64).reshape(-1, 2))])[
            -self.depth:]
        k = self.mask_frame
        if inp.masks is not None and len(inp.masks) and 0 <= k < inp.frame_index:
            tracks = track_back(self.history, k)
            if tracks is not None and len(tracks[0]):
                inp = replace(inp, masks=moved_by_tracks(inp.masks, *tracks, self.min_tracks))
        return self.inner(inp)


class ReplayedMapping:
    """The local BA beside tracking as an online run did it, without a clock: each job is solved when it starts (its
    inputs are copies, so the solution is the same) and is done where the schedule says it was written back (set
    ``now`` to the schedule's answer before each frame)."""

    def __init__(self):
        self.now = False

    @staticmethod
    def start(fn):
        return fn()

    def ready(self, job) -> bool:
        return self.now

    @staticmethod
    def result(job):
        return job

    def close(self) -> None:
        pass


def online_engine(camera, method: str, config: Config, background=None) -> tuple[Engine, TrackedMasks | None]:
    """The engine of an online run (or its replay: ``background`` a :class:`ReplayedMapping`) with ``method``'s
    filter, wrapped in :class:`TrackedMasks` with ``OnlineConfig.mask_tracks`` (then returned too: set its
    ``mask_frame`` before each frame); with ``OnlineConfig.mapping_thread`` its local BA is solved beside tracking
    (``MappingThread``, unless ``background`` is given)."""
    filt = get_method(method).factory(config)
    tracked = None
    if config.online.mask_tracks and filt is not None:
        o = config.online
        depth = int(np.ceil(o.mask_max_age_s * (o.rate_hz if o.rate_hz > 0 else 30.0))) + 2
        filt = tracked = TrackedMasks(filt, o.mask_tracks_min, depth)
    if background is None and config.online.mapping_thread:
        background = MappingThread()
    return Engine(camera, config, filt, background), tracked


class OnlineSLAM:
    """A live-camera API: ``slam = OnlineSLAM(camera, method="d2slam")``, then ``slam.track(frame)`` for each
    frame as it comes (an ``RGBDFrame``: ``rgb``, ``depth`` in metres, ``timestamp``). The segmenter segments the
    newest frame given to :meth:`track` whenever it is free; ``track`` never waits for it. ``slam.close()`` stops the
    segmenter and gives the trajectory and the :class:`Schedule` (arrivals: the frames' timestamps)."""

    def __init__(self, camera, method: str = "d2slam", config: Config = DEFAULT, segmenter=None):
        m = get_method(method)
        if m.runner is not None or m.masks is not None:
            raise D2SlamError(f"--method {method} cannot run online: it is not a keypoint filter of the engine that "
                              "reads a segmenter's masks (online runs: none and the dynamics methods)")
        self.config, self.method = config, method
        self.engine, self.tracked = online_engine(camera, method, config)
        self._clock = time.perf_counter
        self._t0: float | None = None
        self._ts0: float | None = None
        self._offered: tuple[int, np.ndarray] | None = None
        self._taken = -1
        self._lock = threading.Lock()
        self.arrivals: list[float] = []
        self.schedule = Schedule(frames=0, rate_hz=0.0, arrival_s=np.zeros(0))
        self.masks = None
        if m.needs_masks and config.online.masks != "off":
            seg = segmenter if segmenter is not None else online_segmenter(config)
            self.masks = MaskThread(seg, self._next_for_segmenter, (camera.height, camera.width), self._now,
                                    nice=config.online.segmenter_nice)

    def warm_up(self, rgb: np.ndarray | None = None) -> None:
        """Before the first frame, as a live system starts before its camera does: the compiled kernels loaded
        (``d2slam.run.warmup``) and, with a segmenter, its first inference (onnxruntime's first call allocates) on
        ``rgb``."""
        warmup.warm_up()
        if self.masks is not None and rgb is not None:
            self.masks._segmenter(rgb)

    def _now(self) -> float:
        return self._clock() - (self._t0 if self._t0 is not None else self._clock())

    def _next_for_segmenter(self):
        with self._lock:
            if self._offered is None or self._offered[0] <= self._taken:
                return None
            self._taken = self._offered[0]
            return self._offered

    def track(self, frame):
        """Track ``frame`` now (an ``RGBDFrame``, arrived at its timestamp); its result (``TrackResult``)."""
        if self._t0 is None:
            self._t0, self._ts0 = self._clock(), float(frame.timestamp)
        i = len(self.arrivals)
        self.arrivals.append(float(frame.timestamp) - self._ts0)
        if self.masks is not None:
            with self._lock:
                self._offered = (i, frame.rgb)
            self.masks.wake()
        return self.step(i, frame.gray, frame.depth, float(frame.timestamp), np.asarray(self.arrivals))

    def step(self, i: int, gray, depth, timestamp: float, arrival: np.ndarray):
        """Track frame ``i`` now with the masks it reads (:func:`pick_mask`) and record it in the schedule."""
        k, masks = pick_mask(self.masks.latest() if self.masks else None, i, arrival, self.config)
        if self.tracked is not None:
            self.tracked.mask_frame = k
        start = self._now()
        res = self.engine.process(gray, depth, i, timestamp, masks=masks)
        s = self.schedule
        s.processed.append(i)
        s.mask_of.append(k)
        s.start_s.append(start)
        s.done_s.append(self._now())
        if k >= 0:
            s.masks[i] = masks
        if res.mapped:
            s.mapped.append(i)
        return res

    def close(self) -> tuple[Trajectory, Schedule]:
        if self.masks is not None:
            self.masks.close()
            for k, t0, t1 in self.masks.log:
                self.schedule.segmented.append(k)
                self.schedule.seg_start_s.append(t0)
                self.schedule.seg_done_s.append(t1)
        self.schedule.frames = len(self.arrivals)
        self.schedule.arrival_s = np.asarray(self.arrivals, dtype=np.float64)
        self.engine.close()
        _, ts, poses = self.engine.trajectory()
        return Trajectory(ts, poses), self.schedule


@dataclass
class _Frames:
    """A sequence's first ``n`` frames decoded before the clock starts (a camera driver delivers decoded frames):
    grey, depth, colour (when a segmenter reads it) and timestamps."""

    gray: list
    depth: list
    rgb: list | None
    timestamps: np.ndarray


def _preload(seq, n: int, with_rgb: bool, progress: bool | None) -> _Frames:
    gray, depth, rgb, ts = [], [], [] if with_rgb else None, []
    for i in tqdm(range(n), desc=f"decode {getattr(seq, 'name', '')}", unit="frame",
                  disable=None if progress is None else not progress):
        f = seq[i]
        gray.append(f.gray)
        depth.append(f.depth)
        ts.append(float(f.timestamp))
        if with_rgb:
            rgb.append(f.rgb)
    return _Frames(gray, depth, rgb, np.asarray(ts, dtype=np.float64))


@dataclass
class OnlineRun:
    """An online run's trajectory (tracked frames), its schedule, and the engine's frame states by tracked step."""

    trajectory: Trajectory
    schedule: Schedule
    states: list[str]
    keyframes: int
    map_points: int
    wall_s: float

    @property
    def tracked(self) -> int:
        return int(sum(s == "ok" for s in self.states))


def run_online(seq, method: str = "d2slam", config: Config = DEFAULT, frames: int | None = None,
               progress: bool | None = None, segmenter=None) -> OnlineRun:
    """Replay ``seq`` (its first ``frames``) as a live camera at ``OnlineConfig.rate_hz`` (0: its timestamps)
    through :class:`OnlineSLAM`'s parts: the tracker takes the newest arrived frame when free (the others are
    dropped), the segmenter the newest arrived frame when free. ``segmenter``: ``rgb -> persons`` (default: the
    real one, :func:`online_segmenter`)."""
    n = len(seq) if frames is None else min(len(seq), int(frames))
    if n == 0:
        raise D2SlamError("sequence has no frames", path=getattr(seq, "root", None))
    reads_masks = get_method(method).needs_masks and config.online.masks != "off"
    data = _preload(seq, n, reads_masks, progress)
    arrival = arrival_times(data.timestamps, float(config.online.rate_hz))
    slam = OnlineSLAM(seq.camera, method, config, segmenter=segmenter)
    slam.warm_up(data.rgb[0] if reads_masks else None)
    clock = time.perf_counter
    t0 = None
    state = {"taken": -1}

    def for_segmenter():
        elapsed = clock() - t0
        k = newest_arrived(arrival, elapsed)
        if k <= state["taken"]:  # nothing new: the seconds until the next arrival
            return float(arrival[k + 1] - elapsed) if k + 1 < n else None
        state["taken"] = k
        return k, data.rgb[k]

    states = []
    t0 = clock()
    slam._t0 = t0  # the schedule's times count from the first frame's arrival
    if slam.masks is not None:  # the replayed camera feeds the segmenter from now on
        slam.masks._source = for_segmenter
        slam.masks.wake()
    nxt = 0
    while nxt < n:
        i = newest_arrived(arrival, clock() - t0)
        if i < nxt:
            time.sleep(max(0.0, arrival[nxt] - (clock() - t0)))
            continue
        res = slam.step(i, data.gray[i], data.depth[i], float(data.timestamps[i]), arrival)
        states.append(res.state)
        nxt = i + 1
    wall = clock() - t0
    slam.arrivals = list(arrival)
    trajectory, schedule = slam.close()
    schedule.rate_hz = float(config.online.rate_hz)
    schedule.meta.update({"sequence": getattr(seq, "name", ""), "method": method, "config_hash": config.hash(),
                          "masks": config.online.masks if reads_masks else "none"})
    return OnlineRun(trajectory, schedule, states, len(slam.engine.map.good_keyframes()), slam.engine.map.n_points,
                     wall)


def replay(seq, schedule: Schedule, method: str = "d2slam", config: Config = DEFAULT,
           progress: bool | None = None) -> OnlineRun:
    """Run ``schedule`` again, deterministically: the same frames of ``seq`` in the same order, each with the same
    masks, no clock. Its trajectory is the online run's, byte for byte."""

    if schedule.frames > len(seq):
        raise D2SlamError(f"the online schedule has {schedule.frames} frames, the sequence {len(seq)}",
                          path=getattr(seq, "root", None))
    if schedule.meta.get("sequence") not in (None, "", getattr(seq, "name", "")):
        raise D2SlamError(f"the online schedule is of sequence {schedule.meta['sequence']!r}, not "
                          f"{getattr(seq, 'name', '')!r}", path=getattr(seq, "root", None))
    mapping = ReplayedMapping() if config.online.mapping_thread else None
    engine, tracked = online_engine(seq.camera, method, config, mapping)
    mapped = set(schedule.mapped)
    states = []
    t0 = time.perf_counter()
    for i, k in tqdm(list(zip(schedule.processed, schedule.mask_of)), desc=f"replay {getattr(seq, 'name', '')}",
                     unit="frame", disable=None if progress is None else not progress):
        f = seq[i]
        if tracked is not None:
            tracked.mask_frame = k
        if mapping is not None:
            mapping.now = i in mapped
        res = engine.process(f.gray, f.depth, i, float(f.timestamp), masks=schedule.masks[i] if k >= 0 else None)
        states.append(res.state)
    wall = time.perf_counter() - t0
    engine.close()
    _, ts, poses = engine.trajectory()
    return OnlineRun(Trajectory(ts, poses), schedule, states, len(engine.map.good_keyframes()), engine.map.n_points,
                     wall)


TIMING_NOTE = ("an online run depends on timing (the machine, its load): run the same schedule again with "
               "--deterministic LOG.npz, written by --online-log")


def online_report(run: OnlineRun, seq, config: Config, replayed: bool = False) -> dict:
    """The run JSON's ``online`` part and the metrics over the processed frames: :meth:`Schedule.summary`, the
    frames tracked among the processed, ATE/RPE (``metrics`` or ``metrics_error``), the fragment fields (tracked
    against processed: a dropped frame is reported as dropped, not as lost)."""
    s = run.schedule
    out = {"online": {**s.summary(), "tracked": run.tracked, "deterministic": replayed,
                      "masks": s.meta.get("masks"), "mask_max_age_s": config.online.mask_max_age_s,
                      **({} if replayed else {"note": TIMING_NOTE})}}
    gt = seq.groundtruth
    ev = evaluate_run(gt, run.trajectory) if gt is not None and run.tracked >= 3 else None
    if ev is not None and ev.metrics is not None:
        out["metrics"] = ev.metrics.to_dict()
    elif ev is not None and ev.ate_rmse_m is not None:
        out["metrics"] = {"ate_rmse_m": ev.ate_rmse_m}
    else:
        out["metrics_error"] = ("no ATE/RPE: " + ("the sequence has no ground truth" if gt is None else
                                                  ev.error if ev is not None else
                                                  f"only {run.tracked} frames tracked"))
    out.update(fragment_fields(run.tracked, len(s.processed), config.evaluation.min_tracked_share))
    return out


def online_line(report: dict) -> str:
    """What ``d2slam run --online`` prints before its summary line."""
    o = report["online"]
    rate = f"{o['rate_hz']:g} Hz" if o["rate_hz"] > 0 else "the frames' timestamps"
    seg = (f"; segmenter {o['segmenter_fps']:.1f} frames/s, {o['with_mask']} frames with a mask"
           if o["segmented"] else "")
    how = "replayed deterministically" if o["deterministic"] else f"online ({TIMING_NOTE})"
    return (f"{how}: at {rate}, processed {o['processed']}/{o['frames']} frames ({o['dropped']} dropped), lag median "
            f"{o['lag_ms_median']:.1f} ms, p95 {o['lag_ms_p95']:.1f} ms{seg}")


def simulated_schedule(seq, latency: int, config: Config = DEFAULT, frames: int | None = None) -> Schedule:
    """A timing-free online schedule: every frame tracked, the segmenter starting on frame 0 and taking ``latency``
    frames per mask (so its mask of frame ``k`` is ready from frame ``k + latency`` on, and it then starts on that
    frame), each frame reading what :func:`pick_mask` gives it then (``latency`` 0: its own mask, the offline
    protocol). The masks are the real segmenter's from the mask cache. It isolates what stale masks cost in accuracy
    from what a machine's speed costs in dropped frames (``d2slam bench online --latency``)."""
    n = len(seq) if frames is None else min(len(seq), int(frames))
    shape = (seq.camera.height, seq.camera.width)
    arrival = arrival_times(np.asarray(seq.timestamps[:n], dtype=np.float64), float(config.online.rate_hz))
    cache: dict[int, np.ndarray] = {}

    def masks_of(k: int) -> np.ndarray:
        if k not in cache:
            cache[k] = stack_masks(masks_for(seq, k, "onnx", config), shape)
        return cache[k]

    s = Schedule(frames=n, rate_hz=float(config.online.rate_hz), arrival_s=arrival, processed=list(range(n)),
                 meta={"sequence": getattr(seq, "name", ""), "simulated_latency_frames": int(latency)})
    segmented = list(range(0, n, latency)) if latency > 0 else list(range(n))
    for i in range(n):
        if latency <= 0:
            s.mask_of.append(i)
            s.masks[i] = masks_of(i)
            continue
        done = [k for k in segmented if k + latency <= i][-2:]
        latest = None if not done else (done[-1], masks_of(done[-1]),
                                         *((done[0], masks_of(done[0])) if len(done) == 2 else (-1, None)))
        k, m = pick_mask(latest, i, arrival, config)
        s.mask_of.append(k)
        if k >= 0:
            s.masks[i] = m
    s.segmented = segmented
    return s
