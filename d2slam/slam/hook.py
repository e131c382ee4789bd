"""The engine's only contact with dynamics: one keypoint-filter hook, called once per frame.

The engine computes frame-to-frame descriptor matches for *all* keypoints (not only mapped ones), builds a
``FilterInput`` and calls the hook before tracking. The hook returns a per-keypoint dynamic belief in [0, 1];
keypoints above ``EngineConfig.mappoint_belief_threshold`` (0.5) take no part in pose optimisation and create no
map points; the belief is written to the map points they observe, and map points above 0.5 are culled.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np


@dataclass
class FilterInput:
    frame_index: int
    timestamp: float
    gray: np.ndarray | None  # (H, W) uint8; None when the run reads stored features (d2slam.slam.features)
    depth: np.ndarray  # (H, W) float32 metres, 0 = invalid
    K: np.ndarray  # (3, 3)
    kps: np.ndarray  # (N, 2) float32 pixel coordinates (u, v) of the current keypoints (level-0 image)
    kp_depth: np.ndarray  # (N,) float32 metres, 0 = invalid (robust per-keypoint depth used by the engine)
    prev_kps: np.ndarray  # (M, 2) keypoints of the previous frame ((0, 2) on the first frame)
    prev_kp_depth: np.ndarray  # (M,)
    prev_belief: np.ndarray  # (M,) beliefs the hook returned for the previous frame
    matches: np.ndarray  # (K, 2) int: rows (current index, previous index), one-to-one
    mappoint_belief: np.ndarray  # (N,) belief carried by the map point each keypoint was associated to, NaN if none
    masks: np.ndarray | None  # (n, H, W) bool person masks, or None when the run has no segmenter
    # (N,) int pyramid level (ORB octave) of each current keypoint, or None when the engine does not give it. Used by
    # the geometric module to express alpha(z) at the keypoint's detection scale (DynamicsConfig.alpha_octave_scale).
    octave: np.ndarray | None = None
    # (H, W) uint8 grey image of the previous frame, None on the first frame or when it came as stored features. Used
    # by the optional flow correspondences of the geometric module (DynamicsConfig.flow, d2slam.dynamics.flow).
    prev_gray: np.ndarray | None = None
    # (H, W) depth image (metres) of the previous frame, None on the first frame: the depth of the flow's new matches
    # for the pose test (DynamicsConfig.flow_new_depth; the flow itself needs ``prev_gray``).
    prev_depth: np.ndarray | None = None


class KeypointFilter(Protocol):
    """Anything callable on a FilterInput returning (N,) float beliefs in [0, 1] (dynamic probability)."""

    def __call__(self, inp: FilterInput) -> np.ndarray: ...

    def reset(self) -> None: ...
