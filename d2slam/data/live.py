"""A recording replayed as a live camera: when each frame arrives, and which is the newest at a given time.

Both online runs (``d2slam.run.online``: our engine) and the real ORB-SLAM3's online runs
(``d2slam.baselines._orbslam3_worker``) take their frames by these two functions, so both see the same camera.
"""

from __future__ import annotations

import numpy as np


def arrival_times(timestamps, rate_hz: float = 0.0) -> np.ndarray:
    """When each frame arrives, in seconds from the first: its timestamp, or ``i / rate_hz`` when ``rate_hz`` > 0."""
    ts = np.asarray(timestamps, dtype=np.float64)
    if rate_hz > 0:
        return np.arange(len(ts), dtype=np.float64) / float(rate_hz)
    return ts - ts[0] if len(ts) else ts


def newest_arrived(arrival: np.ndarray, elapsed_s: float) -> int:
    """The newest frame that has arrived ``elapsed_s`` seconds after the first (-1: none yet)."""
    return int(np.searchsorted(arrival, elapsed_s, side="right")) - 1
