"""Compiled kernels (numba) of the dynamics modules: integer work whose results are exactly those of the numpy,
OpenCV and scipy code they replace, only faster (``d2slam bench dynamics``; the equality is tested against that
code, ``tests/test_dynamics_kernels.py``).

* ``edge_rows``: the pixels of an edge image (a person mask's edges, ``semantic.MaskEdges``) listed by row;
* ``nearest_sq``: squared Euclidean distance from integer pixels to the nearest of such an edge set, optionally
  bounded: the distance ``scipy.spatial.cKDTree.query`` returns is its square root, and a bounded query finds a
  neighbour exactly when ``d^2 < bound^2`` (scipy compares squared distances with the squared bound). Pixels and
  edges have integer coordinates, so the squares are exact integers and the roots identical.

Kernels are cached on disk by numba (``cache=True``) and release the GIL.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from d2slam.kernel_cache import install as _guard_kernel_cache

_guard_kernel_cache()  # before any kernel is loaded from numba's disk cache


@njit(cache=True, nogil=True)
def edge_rows(img):
    """(start (h + 1,), xs) of the nonzero pixels of a (h, w) uint8 image, by row: the x of row y's pixels are
    ``xs[start[y]:start[y + 1]]``, ascending (the row-major order of ``np.flatnonzero``)."""
    h, w = img.shape
    start = np.zeros(h + 1, np.int64)
    xs = np.empty(h * w, np.int64)
    k = 0
    for y in range(h):
        for x in range(w):
            if img[y, x]:
                xs[k] = x
                k += 1
        start[y + 1] = k
    return start, xs[:k].copy()


@njit(cache=True, nogil=True)
def nearest_sq(start, xs, x0, y0, qx, qy, bound):
    """(P,) float64 squared distance from the pixels (``qx``, ``qy``) (P,) int64 to the nearest edge pixel of an
    ``edge_rows`` set whose crop starts at (``x0``, ``y0``): rows searched outwards from the pixel's row until the
    row distance alone exceeds the best, each row by bisection. ``bound`` > 0: only edge pixels with
    ``d^2 < bound^2`` count, inf when there is none (``bound`` = inf: unbounded)."""
    h = len(start) - 1
    n = len(qx)
    out = np.empty(n, np.float64)
    lim = bound * bound
    for i in range(n):
        best = lim
        px = qx[i] - x0
        py = qy[i] - y0
        dy = 0
        while True:
            if dy * dy >= best:
                break
            lo_row, hi_row = py - dy, py + dy
            if lo_row < 0 and hi_row >= h:
                break
            for side in range(2 if dy > 0 else 1):
                row = lo_row if side == 0 else hi_row
                if row < 0 or row >= h:
                    continue
                a, b = start[row], start[row + 1]
                if a == b:
                    continue
                lo, hi = a, b  # first index with xs >= px
                while lo < hi:
                    mid = (lo + hi) // 2
                    if xs[mid] < px:
                        lo = mid + 1
                    else:
                        hi = mid
                for k in (lo - 1, lo):
                    if a <= k < b:
                        dx = xs[k] - px
                        d2 = float(dx * dx + dy * dy)
                        if d2 < best:
                            best = d2
            dy += 1
        out[i] = best if best < lim else np.inf
    return out
