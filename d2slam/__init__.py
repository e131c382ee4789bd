"""d2slam: a CPU-only, deterministic reproduction of D2SLAM (depth-aware dynamic keypoint rejection for RGB-D SLAM)."""

import os as _os

# Deterministic, explicit thread counts before numpy/scipy load their BLAS (see README "Determinism").
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    _os.environ.setdefault(_var, "1")

__version__ = "0.1.0"

from d2slam.errors import D2SlamError  # noqa: E402,F401
