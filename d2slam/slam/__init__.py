"""The ORB-SLAM3-style RGB-D engine (CONTRIBUTING.md, layout). Its compiled kernels' disk cache is guarded before any
is loaded (:mod:`d2slam.kernel_cache`)."""

from d2slam.kernel_cache import install as _guard_kernel_cache

_guard_kernel_cache()
