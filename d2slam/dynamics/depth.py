"""Depth-adaptive quantities of D2SLAM (eq 2, 5, 9, 10); the robust per-keypoint depth is the engine's
(``d2slam.slam.depth``, re-exported here).

The paper gives a range and a direction for each depth-adaptive quantity, not the mapping.
docs/design.md#depth-adaptive-quantities-eq-2-5-9-10 fixes the reading used here, with the normalised depth

    s(z) = clip((z - z_near) / (z_far - z_near), 0, 1),      z_near = 0.5 m, z_far = 4.5 m

    beta(z)  = beta_min + (beta_max - beta_min) s(z)          eq 2,  in [0.05, 0.25], proportional to depth
    alpha(z) = alpha_max - (alpha_max - alpha_min) s(z)       eq 5,  in [0.5, 0.9] px, inversely proportional
    delta(z) = clip(delta_a - delta_b z, delta_min, delta_max) eq 9, 48 - 4 z px, in [11, 48]
    gamma(z) = gamma_max - (gamma_max - gamma_min) s(z)       eq 10, in [10, 28] px, inversely proportional

A depth is *valid* when it is finite and > 0 (0 = invalid, the project convention). Every function returns the
midpoint of its range for an invalid depth (beta 0.15, alpha 0.7, delta 29.5, gamma 19), and for every depth when
``use_depth=False`` (the "no-depth" ablation). All functions are vectorised over arrays of any shape.

Deviation (see ``octave_factor``): the epipolar threshold used by the geometric module is
alpha(z) * 1.2^octave (1.2: the engine's pyramid scale), alpha at the keypoint's detection scale, in every mode that
has an epipolar threshold.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from d2slam.data.config import DepthNoise
from d2slam.dynamics.config import DynamicsConfig
from d2slam.errors import D2SlamError
from d2slam.slam.config import OrbConfig
from d2slam.slam.depth import keypoint_depth, keypoint_depth_range, valid_depth  # noqa: F401 - the engine's, shared

_DEFAULT = DynamicsConfig()
_ORB = OrbConfig()  # the engine's defaults; a run's come with the hook's input (FilterInput)
_NOISE = DepthNoise()  # a Kinect's; a run's is its camera's (FilterInput.camera)


def normalised_depth(z: np.ndarray, cfg: DynamicsConfig = _DEFAULT) -> np.ndarray:
    """s(z) = clip((z - z_near) / (z_far - z_near), 0, 1); NaN where the depth is invalid."""
    z = np.asarray(z, dtype=np.float64)
    ok = valid_depth(z)
    s = np.clip((np.where(ok, z, 0.0) - cfg.z_near) / (cfg.z_far - cfg.z_near), 0.0, 1.0)
    return np.where(ok, s, np.nan)


def _linear(z, lo_at_near: float, hi_at_far: float, cfg: DynamicsConfig, use_depth: bool) -> np.ndarray:
    """lo_at_near + (hi_at_far - lo_at_near) s(z), the midpoint where z is invalid or use_depth is False."""
    z = np.asarray(z, dtype=np.float64)
    mid = 0.5 * (lo_at_near + hi_at_far)
    if not use_depth:
        return np.full(z.shape, mid)
    s = normalised_depth(z, cfg)
    return np.where(np.isnan(s), mid, lo_at_near + (hi_at_far - lo_at_near) * np.nan_to_num(s))


def beta(z, cfg: DynamicsConfig = _DEFAULT, use_depth: bool = True) -> np.ndarray:
    """eq 2: beta(z) = beta_min + (beta_max - beta_min) s(z), the logistic slope (1/px), proportional to depth."""
    return _linear(z, cfg.beta_min, cfg.beta_max, cfg, use_depth)


def alpha(z, cfg: DynamicsConfig = _DEFAULT, use_depth: bool = True) -> np.ndarray:
    """eq 5: alpha(z) = alpha_max - (alpha_max - alpha_min) s(z), the epipolar threshold (px), inversely
    proportional to depth."""
    return _linear(z, cfg.alpha_max, cfg.alpha_min, cfg, use_depth)


def octave_factor(octave, n: int, scale_factor: float = _ORB.scale_factor, at_scale: bool = True
                  ) -> np.ndarray | float:
    """eq 5 (ours, a deviation): the factor ``scale_factor ** octave`` that expresses the epipolar threshold at each
    keypoint's detection scale (ORB-SLAM's per-level sigma; ``scale_factor``: the engine's pyramid scale,
    ``FilterInput.scale_factor``).

    Why: an ORB keypoint detected at pyramid level k is localised on a grid ``1.2^k`` px wide at level 0, so the
    epipolar error of correct static matches grows with the level; with alpha(z) * 1.2^k the share of them above the
    threshold is about the same at every level (measured: docs/deviations.md, ``OursConfig.alpha_at_scale``).
    ``octave`` None (the engine gives no levels), ``at_scale`` False or a scale of 1 -> 1.0 (the paper as printed).
    Octaves are clipped to [0, 31] (NaN -> 0); an array whose length is not ``n`` (the keypoint count) is a
    D2SlamError."""
    if octave is None or not at_scale or scale_factor == 1.0:
        return 1.0
    o = np.asarray(octave).reshape(-1)
    if len(o) != n:
        raise D2SlamError(f"octave has {len(o)} entries for {n} keypoints")
    o = np.clip(np.nan_to_num(o.astype(np.float64), nan=0.0), 0, 31)
    return float(scale_factor) ** o


def gamma(z, cfg: DynamicsConfig = _DEFAULT, use_depth: bool = True) -> np.ndarray:
    """eq 10: gamma(z) = gamma_max - (gamma_max - gamma_min) s(z), the OIM centroid threshold (px)."""
    return _linear(z, cfg.gamma_max, cfg.gamma_min, cfg, use_depth)


def delta(z, cfg: DynamicsConfig = _DEFAULT, use_depth: bool = True) -> np.ndarray:
    """eq 9: delta(z) = clip(48 - 4 z, 11, 48), the OIM neighbourhood radius (px). Not a function of s(z): the
    paper prints this one. Midpoint 29.5 px where z is invalid or use_depth is False."""
    z = np.asarray(z, dtype=np.float64)
    mid = 0.5 * (cfg.delta_min + cfg.delta_max)
    if not use_depth:
        return np.full(z.shape, mid)
    ok = valid_depth(z)
    d = np.clip(cfg.delta_a - cfg.delta_b * np.where(ok, z, 0.0), cfg.delta_min, cfg.delta_max)
    return np.where(ok, d, mid)


def depth_sigma(z, noise: DepthNoise = _NOISE) -> np.ndarray:
    """sigma(z) of the camera's depth noise (``Camera.depth_noise``: a Kinect's, Nguyen et al. 2012), the scale of the
    pose test's depth residual (ours, see ``geometric.pose_residuals``). NaN where the depth is invalid."""
    return noise.sigma(z)


def depth_edge(depth: np.ndarray, px: np.ndarray, z: np.ndarray, cfg: DynamicsConfig = _DEFAULT,
               radius: int = _ORB.depth_patch_radius, noise: DepthNoise = _NOISE) -> np.ndarray:
    """(N,) bool: the keypoint's depth patch (the engine's, of ``radius``: ``FilterInput.depth_patch_radius``) spans
    more than the noise can: its range exceeds the ``noise_confidence`` quantile of the range of that many samples of
    sigma(z) (the studentized range). ``px`` where the keypoints are in the depth image, ``z`` their robust depths."""
    q = range_quantile(cfg.ours.noise_confidence, (2 * int(radius) + 1) ** 2)
    with np.errstate(invalid="ignore"):
        return keypoint_depth_range(depth, px, radius) > q * depth_sigma(z, noise)


@lru_cache(maxsize=None)
def range_quantile(confidence: float, n: int) -> float:
    """The ``confidence`` quantile of the range of ``n`` samples of a unit normal (the studentized range with
    infinite degrees of freedom: 4.39 for 9 samples at 95 %); computed once per (confidence, n)."""
    from scipy.stats import studentized_range

    return float(studentized_range.ppf(confidence, n, 1e6))  # 1e6 degrees of freedom: infinite, and fast


def uncertainty_width(b: np.ndarray, cfg: DynamicsConfig = _DEFAULT) -> np.ndarray:
    """eq 2 / fig 2: half-width (px) of the mask's uncertainty zone for slope ``b``: P_S stays within
    (1 - p, p) for |d| < ln(p / (1 - p)) / beta, p = ``uncertainty_prob`` (0.75 -> ln 3 / beta)."""
    p = cfg.uncertainty_prob
    return np.log(p / (1.0 - p)) / np.asarray(b, dtype=np.float64)


class DepthMaps:
    """beta, alpha, delta, gamma (eq 2, 5, 9, 10) of one frame's keypoint depths, computed once and shared by the
    modules: the same values as ``beta(z)``, ``alpha(z)``, ``delta(z)``, ``gamma(z)`` (s(z) and the validity test are
    evaluated once instead of once per quantity). ``valid`` (N,) bool is ``valid_depth(z)``."""

    __slots__ = ("z", "valid", "beta", "alpha", "delta", "gamma")

    def __init__(self, z, cfg: DynamicsConfig = _DEFAULT, use_depth: bool = True):
        z = np.asarray(z, dtype=np.float64)
        self.z = z
        with np.errstate(invalid="ignore"):
            ok = np.isfinite(z) & (z > 0)
        self.valid = ok
        if not use_depth:
            self.beta = np.full(z.shape, 0.5 * (cfg.beta_min + cfg.beta_max))
            self.alpha = np.full(z.shape, 0.5 * (cfg.alpha_max + cfg.alpha_min))
            self.delta = np.full(z.shape, 0.5 * (cfg.delta_min + cfg.delta_max))
            self.gamma = np.full(z.shape, 0.5 * (cfg.gamma_max + cfg.gamma_min))
            return
        z0 = np.where(ok, z, 0.0)
        s = np.clip((z0 - cfg.z_near) / (cfg.z_far - cfg.z_near), 0.0, 1.0)

        def lin(lo, hi):
            return np.where(ok, lo + (hi - lo) * s, 0.5 * (lo + hi))

        self.beta = lin(cfg.beta_min, cfg.beta_max)
        self.alpha = lin(cfg.alpha_max, cfg.alpha_min)
        self.gamma = lin(cfg.gamma_max, cfg.gamma_min)
        self.delta = np.where(ok, np.clip(cfg.delta_a - cfg.delta_b * z0, cfg.delta_min, cfg.delta_max),
                              0.5 * (cfg.delta_min + cfg.delta_max))
