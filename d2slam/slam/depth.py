"""Per-keypoint depth from the depth image: which depths are valid, and the robust depth of a keypoint (the median
of its patch). The engine reads it for every frame (``slam/frame.py``); the dynamics modules read the same."""

from __future__ import annotations

import numpy as np


def valid_depth(z: np.ndarray) -> np.ndarray:
    """Boolean array: depth finite and strictly positive (0, negative, NaN and inf are invalid)."""
    z = np.asarray(z, dtype=np.float64)
    with np.errstate(invalid="ignore"):
        return np.isfinite(z) & (z > 0)


def _patches(depth: np.ndarray, kps: np.ndarray, radius: int) -> tuple[np.ndarray, np.ndarray]:
    """((N, (2 radius + 1)^2) depths of each keypoint's patch around its rounded pixel, (N, P) bool: the pixel is in
    the image with a valid depth (never for a non-finite keypoint))."""
    r = int(radius)
    kps = np.asarray(kps, dtype=np.float64).reshape(-1, 2)
    depth = np.asarray(depth)
    h, w = depth.shape
    finite = np.all(np.isfinite(kps), axis=1)
    c = np.where(finite[:, None], np.rint(kps), -10 * (r + 1)).astype(np.int64)
    off = np.arange(-r, r + 1)
    du, dv = np.meshgrid(off, off)
    u = c[:, 0:1] + du.ravel()[None, :]
    v = c[:, 1:2] + dv.ravel()[None, :]
    inside = (u >= 0) & (u < w) & (v >= 0) & (v < h)
    vals = depth[np.clip(v, 0, h - 1), np.clip(u, 0, w - 1)].astype(np.float64)
    return vals, inside & valid_depth(vals)


def keypoint_depth(depth: np.ndarray, kps: np.ndarray, radius: int) -> np.ndarray:
    """Robust depth of each keypoint: median of the valid pixels of the (2 radius + 1)^2 patch around its rounded
    pixel.

    ``depth`` (H, W) metres (0 / NaN / inf invalid), ``kps`` (N, 2) pixel (u, v). Patch pixels outside the image are
    ignored; a keypoint with no valid patch pixel (or a non-finite position) gets 0 (invalid). Vectorised: the patches
    are gathered as an (N, P) array, invalid entries sorted to the end as +inf, and the median is read at the middle
    of each row's valid count (mean of the two middle values when the count is even).
    """
    vals, ok = _patches(depth, kps, radius)
    n = len(vals)
    if n == 0:
        return np.zeros(0, dtype=np.float32)
    vals = np.sort(np.where(ok, vals, np.inf), axis=1)
    cnt = ok.sum(axis=1)
    lo = np.maximum((cnt - 1) // 2, 0)
    hi = np.maximum(cnt // 2, 0)
    rows = np.arange(n)
    med = 0.5 * (vals[rows, lo] + vals[rows, np.minimum(hi, vals.shape[1] - 1)])
    return np.where(cnt > 0, med, 0.0).astype(np.float32)


def keypoint_depth_range(depth: np.ndarray, kps: np.ndarray, radius: int) -> np.ndarray:
    """(N,) max - min of the valid depths of each keypoint's (2 radius + 1)^2 patch (the patch of
    :func:`keypoint_depth`), NaN with fewer than two valid pixels: how far the patch spans a depth edge."""
    vals, ok = _patches(depth, kps, radius)
    if len(vals) == 0:
        return np.zeros(0)
    spread = np.where(ok, vals, -np.inf).max(axis=1) - np.where(ok, vals, np.inf).min(axis=1)
    return np.where(ok.sum(axis=1) >= 2, spread, np.nan)
