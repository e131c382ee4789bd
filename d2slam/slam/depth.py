"""Per-keypoint depth from the depth image: which depths are valid, and the robust depth of a keypoint (the median
of its patch). The engine reads it for every frame (``slam/frame.py``); the dynamics modules read the same.

The patches are read by a compiled kernel (numba), one keypoint at a time: a patch has at most (2 r + 1)^2 pixels, and
gathering them as an (N, P) array with numpy costs more than the statistics themselves."""

from __future__ import annotations

import numpy as np
from numba import njit


def valid_depth(z: np.ndarray) -> np.ndarray:
    """Boolean array: depth finite and strictly positive (0, negative, NaN and inf are invalid)."""
    z = np.asarray(z, dtype=np.float64)
    with np.errstate(invalid="ignore"):
        return np.isfinite(z) & (z > 0)


@njit(cache=True, nogil=True)
def _patch_stats(depth, cu, cv, radius):
    """(median (N,), max - min (N,), count (N,)) of the valid depths (finite, > 0) of the (2 radius + 1)^2 patch
    around each pixel (``cu``, ``cv``) (N,) int64, pixels outside the image ignored; the median is the mean of the two
    middle values for an even count, 0 and NaN for a patch without a valid depth."""
    h, w = depth.shape
    n = len(cu)
    med = np.zeros(n, np.float64)
    spread = np.full(n, np.nan)
    count = np.zeros(n, np.int64)
    vals = np.empty((2 * radius + 1) ** 2, np.float64)
    for i in range(n):
        k = 0
        for v in range(cv[i] - radius, cv[i] + radius + 1):
            if v < 0 or v >= h:
                continue
            for u in range(cu[i] - radius, cu[i] + radius + 1):
                if u < 0 or u >= w:
                    continue
                x = np.float64(depth[v, u])
                if np.isfinite(x) and x > 0:
                    j = k  # insertion sort: a patch holds a few values
                    while j > 0 and vals[j - 1] > x:
                        vals[j] = vals[j - 1]
                        j -= 1
                    vals[j] = x
                    k += 1
        count[i] = k
        if k > 0:
            med[i] = 0.5 * (vals[(k - 1) // 2] + vals[k // 2])
            spread[i] = vals[k - 1] - vals[0]
    return med, spread, count


def _patches(depth: np.ndarray, kps: np.ndarray, radius: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``_patch_stats`` of each keypoint's patch around its rounded pixel (no valid pixel for a non-finite
    keypoint)."""
    r = int(radius)
    kps = np.asarray(kps, dtype=np.float64).reshape(-1, 2)
    finite = np.all(np.isfinite(kps), axis=1)
    c = np.where(finite[:, None], np.rint(kps), -10 * (r + 1)).astype(np.int64)
    return _patch_stats(np.asarray(depth), np.ascontiguousarray(c[:, 0]), np.ascontiguousarray(c[:, 1]), r)


def keypoint_depth(depth: np.ndarray, kps: np.ndarray, radius: int) -> np.ndarray:
    """Robust depth of each keypoint: median of the valid pixels of the (2 radius + 1)^2 patch around its rounded
    pixel.

    ``depth`` (H, W) metres (0 / NaN / inf invalid), ``kps`` (N, 2) pixel (u, v). Patch pixels outside the image are
    ignored; a keypoint with no valid patch pixel (or a non-finite position) gets 0 (invalid). The median of an even
    count is the mean of the two middle values.
    """
    return _patches(depth, kps, radius)[0].astype(np.float32)


def keypoint_depth_range(depth: np.ndarray, kps: np.ndarray, radius: int) -> np.ndarray:
    """(N,) max - min of the valid depths of each keypoint's (2 radius + 1)^2 patch (the patch of
    :func:`keypoint_depth`), NaN with fewer than two valid pixels: how far the patch spans a depth edge."""
    _, spread, count = _patches(depth, kps, radius)
    return np.where(count >= 2, spread, np.nan)
