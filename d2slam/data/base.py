"""The one interface every dataset implements (TUM folders, synthetic sequences): cameras, frames, trajectories.

Poses are 4x4 float64 ``T_world_camera`` (camera-to-world, the TUM ground-truth convention: a point ``X_c`` in the
camera frame is ``T @ X_c`` in the world). Depth is float32 metres with 0 = invalid. RGB is HxWx3 uint8 in RGB order.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Iterator, Protocol, runtime_checkable

import cv2
import numpy as np

from d2slam.data.config import DepthNoise


@dataclass(frozen=True)
class Camera:
    """Pinhole RGB-D camera. ``dist`` are OpenCV coefficients (k1, k2, p1, p2, k3); ``bf`` is the virtual baseline
    times fx used for the RGB-D "virtual stereo" coordinate ``u_R = u - bf / z`` (ORB-SLAM convention);
    ``depth_noise`` its depth sensor's noise model (a Kinect's by default)."""

    fx: float
    fy: float
    cx: float
    cy: float
    width: int = 640
    height: int = 480
    dist: tuple[float, float, float, float, float] = (0.0, 0.0, 0.0, 0.0, 0.0)
    depth_factor: float = 5000.0
    bf: float = 40.0
    name: str = "custom"
    depth_noise: DepthNoise = DepthNoise()

    @property
    def K(self) -> np.ndarray:
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def has_distortion(self) -> bool:
        return any(abs(c) > 0 for c in self.dist)


@dataclass
class RGBDFrame:
    """One associated RGB-D frame."""

    index: int
    timestamp: float  # RGB timestamp (s); the frame's time
    depth_timestamp: float
    rgb: np.ndarray  # (H, W, 3) uint8, RGB order
    depth: np.ndarray | None  # (H, W) float32 metres, 0 = invalid; None when only the colour was read
    rgb_path: Path | None = None
    depth_path: Path | None = None

    @cached_property
    def gray(self) -> np.ndarray:
        """The grey image, converted on first use and kept: a run reads it twice (extraction, then the filter)."""
        return cv2.cvtColor(self.rgb, cv2.COLOR_RGB2GRAY)


@dataclass
class Trajectory:
    """Timestamped poses: ``timestamps`` (N,) strictly increasing, ``poses`` (N, 4, 4) ``T_world_camera``."""

    timestamps: np.ndarray
    poses: np.ndarray
    meta: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.timestamps)


@runtime_checkable
class Sequence(Protocol):
    """A sequence of RGB-D frames with a camera and (optionally) ground truth. Iteration is lazy: images are read
    when a frame is requested."""

    name: str
    root: Path
    camera: Camera
    timestamps: np.ndarray  # RGB timestamps of the associated frames, increasing
    def __len__(self) -> int: ...
    def __getitem__(self, index: int) -> RGBDFrame: ...
    def __iter__(self) -> Iterator[RGBDFrame]: ...

    @property
    def groundtruth(self) -> Trajectory | None: ...
