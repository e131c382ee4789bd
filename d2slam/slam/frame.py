"""Frames: one tracked frame's keypoints as arrays (:class:`Frame`), with their depth and the RGB-D "virtual stereo"
coordinate (:func:`virtual_right`); the extractor that makes them is ``d2slam.slam.extractor``."""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from d2slam.config import EngineConfig
from d2slam.data.base import Camera
from d2slam.slam.matching import Gridded


@dataclass
class Frame(Gridded):
    """One tracked frame (arrays indexed by keypoint). ``Tcw`` is world-to-camera (ORB-SLAM convention)."""

    index: int
    timestamp: float
    kps: np.ndarray  # (N, 2) float64 undistorted pixel coordinates
    kps_raw: np.ndarray  # (N, 2) float64 detected (distorted) coordinates
    octave: np.ndarray  # (N,) int
    angle: np.ndarray  # (N,) float32 degrees
    desc: np.ndarray  # (N, 32) uint8
    depth: np.ndarray  # (N,) float64 metres, 0 = invalid
    ur: np.ndarray  # (N,) float64 virtual right coordinate u - bf/z for close points, -1 otherwise
    inv_sigma2: np.ndarray  # (N,) 1 / scale^(2 octave)
    mp: np.ndarray = field(default=None)  # (N,) int map point id, -1 none
    outlier: np.ndarray = field(default=None)  # (N,) bool
    belief: np.ndarray | None = None  # (N,) dynamic belief from the hook (None: no filter)
    Tcw: np.ndarray | None = None
    ref_kf: int = -1
    grids: dict = field(default_factory=dict, repr=False)  # cell size -> KeypointGrid (``Gridded.grid``)

    def __post_init__(self):
        n = len(self.kps)
        if self.mp is None:
            self.mp = np.full(n, -1, dtype=np.int64)
        if self.outlier is None:
            self.outlier = np.zeros(n, dtype=bool)

    @property
    def n(self) -> int:
        return len(self.kps)

    @property
    def dynamic(self) -> np.ndarray:
        if self.belief is None:
            return np.zeros(self.n, dtype=bool)
        return self.belief > 0.5


def empty_frame(index: int, timestamp: float) -> Frame:
    z = np.zeros(0)
    return Frame(index=index, timestamp=timestamp, kps=np.zeros((0, 2)), kps_raw=np.zeros((0, 2)),
                 octave=np.zeros(0, dtype=np.int64), angle=np.zeros(0, dtype=np.float32),
                 desc=np.zeros((0, 32), dtype=np.uint8), depth=z, ur=z.copy(), inv_sigma2=z.copy())


def undistort(pts: np.ndarray, camera: Camera) -> np.ndarray:
    """Undistorted pixel coordinates (identity when the camera has no distortion)."""
    if not camera.has_distortion or len(pts) == 0:
        return pts.copy()
    out = cv2.undistortPoints(pts.reshape(-1, 1, 2).astype(np.float64), camera.K, np.asarray(camera.dist),
                              P=camera.K)
    return out.reshape(-1, 2)


def close_depth(camera: Camera, engine: EngineConfig) -> float:
    """ORB-SLAM's close-point depth ``th_depth * b`` with baseline ``b = bf / fx`` (40 * 40 / 535.4 ≈ 3 m)."""
    return engine.th_depth * camera.bf / camera.fx


def virtual_right(u: np.ndarray, z: np.ndarray, bf: float, th_depth_m: float) -> np.ndarray:
    """``u_R = u - bf / z`` for keypoints with depth below ``th_depth_m`` (stereo edges); -1 marks the others
    (monocular edges), as ORB-SLAM's ``mvuRight < 0``. ORB-SLAM's ``ComputeStereoFromRGBD`` sets ``u_R`` for every
    valid depth (``th_depth_m = inf``, ``EngineConfig.stereo_far_points``); with it off only close points
    (``th_depth * b``) get stereo edges."""
    close = (z > 0) & (z < th_depth_m)
    ur = np.full(len(u), -1.0)
    ur[close] = u[close] - bf / z[close]
    return ur
