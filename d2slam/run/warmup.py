"""Compile the engine's and the filter's kernels (numba) once, ahead of the first run.

The kernels (``d2slam.slam.lm``, ``d2slam.slam.matching``, ``d2slam.dynamics.kernels``) are compiled on first use
and cached on disk by numba (``cache=True``): beside their source (``__pycache__``) when the package folder is
writable, else in numba's user-wide cache (``~/.cache/numba``; ``$NUMBA_CACHE_DIR`` overrides both). Every later
process, a study's workers included, loads them from there instead of compiling (``d2slam bench startup``). Compiling
them all costs about 20 CPU-seconds, most of it the Levenberg-Marquardt kernels of ``d2slam.slam.lm``; loading them
well under a second.

``warm_up`` runs the engine with the ``d2slam`` filter on a few frames of the analytic room
(``d2slam.slam.fixture``) with a person mask, so that every kernel is compiled (or loaded) with the argument types of
real runs. ``make demo`` and ``make test`` call it once per install, after fetching the assets (``python -m
d2slam.run.warmup``; its engine closes loops with the vocabulary, built from the real TUM frames), so that the first
run of a fresh install finds them compiled, and the study calls it before its workers start, so that they do not each compile the same kernels.
"""

from __future__ import annotations

import time

import numpy as np

from d2slam.config import DEFAULT
from d2slam.run.methods import get_filter
from d2slam.run.sequence import ensure_vocabulary
from d2slam.slam.engine import Engine
from d2slam.slam.fixture import FR3, room_sequence

#: Frames of the analytic room the warm-up runs (enough for keyframes, local BA and the filter's every kernel).
WARM_UP_FRAMES = 24


def warm_up(frames: int = WARM_UP_FRAMES) -> float:
    """Compile (or load from the cache) every compiled kernel; returns the seconds it took."""
    t0 = time.perf_counter()
    images, _, ts = room_sequence(int(frames), seed=0)
    mask = np.zeros((1, FR3.height, FR3.width), dtype=bool)
    mask[0, FR3.height // 4:3 * FR3.height // 4, FR3.width // 3:FR3.width // 2] = True  # a person-sized region
    ensure_vocabulary(DEFAULT)
    engine = Engine(FR3, DEFAULT, get_filter("d2slam", DEFAULT))
    try:
        for i, (gray, depth) in enumerate(images):
            engine.process(gray, depth, i, float(ts[i]), masks=mask)
    finally:
        engine.close()
    return time.perf_counter() - t0


if __name__ == "__main__":
    print("d2slam: compiling the engine's kernels (numba, cached on disk: once per install)", flush=True)
    print(f"d2slam: kernels ready ({warm_up():.1f} s)")
