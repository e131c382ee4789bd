"""Data settings: TUM reading and downloading (docs/design.md#tum-data)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from d2slam.ranges import Checked, below, within


# The feature budget's bound (docs/inputs.md): OpenCV 5.0's ORB allocates for nfeatures up front and fails with
# std::bad_alloc from 2^29; a 640x480 image of noise yields at most 63,077 ORB keypoints at FAST 20 (8 levels, scale
# 1.2), so no frame fills a budget beyond 100,000 (the extractor asks for n_features x oversample x refill_max).
ORB_FEATURES_WHY = ("the maximum is more than any frame yields: a 640x480 image of noise gives 63,077 ORB "
                    "keypoints; OpenCV's ORB fails from 2^29")


@dataclass(frozen=True)
class DataConfig(Checked):
    # RGB/depth association tolerance (s), TUM associate.py convention (strict <).
    max_dt: float = within(0.02, 0.0, 10.0, lo_open=True)
    # Ground-truth interpolation refuses to bridge gaps longer than this (s); TUM mocap runs at 100 Hz.
    gt_max_gap: float = within(0.1, 0.0, 100.0, lo_open=True)
    # Trajectory validation: |q| - 1 tolerance and rotation orthonormality tolerance.
    quaternion_norm_tolerance: float = within(1e-2, 0.0, 1.0, lo_open=True)
    rotation_tolerance: float = within(1e-5, 0.0, 1.0, lo_open=True)
    # `d2slam download`: connect/read timeout (s) so an unreachable server fails fast.
    download_timeout: float = within(10.0, 0.0, 10_000.0, lo_open=True)
    # Depth-scale check of `d2slam run` without ground truth or camera motion (else DepthCheckConfig's): the median
    # valid depth (m) of the first depth_check_frames frames must lie in depth_median_range (an indoor RGB-D scene;
    # metres read as 1/5000 m move it out, not every factor of 5); otherwise a warning names the factor that would bring
    # it in.
    depth_check_frames: int = within(5, 1, 100_000)
    depth_median_range: tuple[float, float] = within((0.7, 10.0), 0.0, 1000.0, lo_open=True, ascending=True)
    # Depth factors the warning suggests: millimetres, TUM's 1/5000 m, metres.
    depth_factor_candidates: tuple[float, ...] = within((1000.0, 5000.0, 1.0), 0.0, 1e6, lo_open=True)


@dataclass(frozen=True)
class DepthCheckConfig(Checked):
    """The depth-scale check of ``d2slam run`` (:mod:`d2slam.data.depth_scale`); nothing here changes a run's numbers
    (a section of ``d2slam.config.CliConfig``, not of ``Config``)."""

    _RULES = (below("depth_min_baseline_m", "depth_max_baseline_m"),)
    # Depth-scale check of `d2slam run` against the ground truth's camera motion (d2slam.data.depth_scale): among
    # depth_candidate_frames frames spread over the sequence, up to depth_pairs pairs (one per first frame, spread over
    # the sequence) whose ground-truth poses are depth_min_baseline_m to depth_max_baseline_m apart and turn by at most
    # depth_max_rotation_deg (the views overlap); per frame depth_orb_features ORB keypoints with depth, cross-checked
    # Hamming matches within depth_max_hamming; the relative pose by a 3-D/3-D RANSAC (depth_ransac_iterations
    # hypotheses of 3 matches, seeded with the run's seed, EngineConfig.seed; inlier when the residual is within
    # depth_inlier_rel of the point's depth, which does not depend on the scale) with at least depth_min_inliers
    # inliers. The depth is off when the median ratio of the estimated to the true camera translation is beyond
    # depth_ratio_tolerance either way (a factor 5, e.g. millimetres read with TUM's 5000, gives 0.2 or 5). Without
    # ground truth or camera motion, DataConfig's median-depth window decides, and the depth_far_percentile of the valid
    # depth must reach depth_far_min_m (a room's far side; millimetres read as 1/5000 m bring it within a metre).
    depth_candidate_frames: int = within(300, 2, 1_000_000)
    depth_pairs: int = within(5, 1, 1000)
    depth_min_baseline_m: float = within(0.05, 0.0, 100.0)
    depth_max_baseline_m: float = within(0.5, 0.0, 100.0, lo_open=True)
    depth_max_rotation_deg: float = within(20.0, 0.0, 180.0)
    depth_orb_features: int = within(600, 1, 100_000, why=ORB_FEATURES_WHY)
    depth_max_hamming: int = within(50, 0, 256)
    depth_ransac_iterations: int = within(200, 1, 1_000_000)
    depth_inlier_rel: float = within(0.02, 0.0, 1.0, lo_open=True)
    depth_min_inliers: int = within(30, 3, 100_000)
    depth_ratio_tolerance: float = within(2.0, 1.0, 1000.0, lo_open=True)
    depth_far_percentile: float = within(95.0, 0.0, 100.0)
    depth_far_min_m: float = within(1.0, 0.0, 100.0)


@dataclass(frozen=True)
class DepthNoise(Checked):
    """An RGB-D camera's axial depth noise, sigma(z) = a + b (z - c)^2 metres (Nguyen et al. 2012; a Kinect's: ~1.2 mm
    at 0.4 m, ~2 mm at 1 m, ~13 mm at 3 m; docs/design.md#depth-noise): what the synthetic sensor draws
    (``d2slam.synth.sensor``) and the scale of the pose test's depth residual (``d2slam.dynamics``). A camera's own
    (``Camera.depth_noise``); the TUM cameras and the synthetic one are Kinects."""

    a: float = within(0.0012, 0.0, 1.0)
    b: float = within(0.0019, 0.0, 1.0)
    c: float = within(0.4, 0.0, 20.0)

    def sigma(self, z):
        """sigma(z) (float64, like ``z``'s shape); NaN where ``z`` is not a valid depth (finite and > 0)."""
        z = np.asarray(z, dtype=np.float64)
        with np.errstate(invalid="ignore"):
            valid = np.isfinite(z) & (z > 0)
        return np.where(valid, self.a + self.b * (z - self.c) ** 2, np.nan)
