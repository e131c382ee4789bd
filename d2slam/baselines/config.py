"""The baselines' settings: the real ORB-SLAM3 (pyorbslam3) and the DBoW2 vocabulary the project builds for it
(``BaselineConfig``), and the people removed from its frames for ``orbslam3-masked`` (``MaskingConfig``)."""

from __future__ import annotations

from dataclasses import dataclass

from d2slam.ranges import Checked, below, one_of, section, seed, text, within
from d2slam.segmentation.config import SegmentationConfig


# `orbslam3-masked`'s RGB fills (MaskingConfig.fill; d2slam.baselines.masking).
MASK_FILLS = ("black", "mean", "blur", "pushpull", "telea", "ns")


@dataclass(frozen=True)
class BaselineConfig(Checked):
    _RULES = (below("vocab_levelsup", "vocab_levels", strict=False),)
    # DBoW2 tree: branching k, depth L (the official ORBvoc.txt: 10, 6), ORB-SLAM3's FeatureVector level
    # (levelsup = 4 levels above the leaves), k-majority iterations per level, training seed.
    vocab_k: int = within(10, 2, 20, why="ORB-SLAM3's vocabulary loader")
    vocab_levels: int = within(6, 1, 10, why="ORB-SLAM3's vocabulary loader")
    vocab_levelsup: int = within(4, 0, 10)
    vocab_max_iter: int = within(10, 1, 1000)
    vocab_seed: int = seed(0)
    # Synthetic training sequences (seeds 900-999 are reserved for the vocabulary): seeds, scenarios, frames per
    # sequence, every n-th frame used.
    vocab_train_seeds: tuple[int, ...] = within(
        (900, 901), 900, 999, why="seeds 900-999 are the vocabulary's; benchmarks use the others")
    vocab_train_scenarios: tuple[str, ...] = one_of(
        ("walking_xyz", "walking_halfsphere", "walking_rpy", "sitting_static"), "d2slam.synth.scene:SCENARIOS",
        lazy=True)
    vocab_train_frames: int = within(60, 1, 100_000)
    vocab_train_stride: int = within(6, 1, 100_000)
    # A build is announced with its estimate: a + b x frames to render + c x training images (CPU seconds, measured:
    # docs/orbslam3_baseline.md); without a terminal each stage logs a line on stderr every this many seconds.
    vocab_estimate_s: tuple[float, float, float] = within((3.0, 0.15, 0.15), 0.0, 10_000.0)
    vocab_log_interval_s: float = within(5.0, 0.0, 10_000.0)
    # ORB-SLAM3 run: camera fps written in the settings, repeats of the study (its threads are not deterministic: the
    # study reports the median and spread of the repeats per sequence; docs/deviations.md), subprocess time limits
    # (vocabulary load + per frame).
    orbslam3_fps: float = within(30.0, 0.0, 1000.0, lo_open=True)
    orbslam3_repeats: int = within(3, 1, 100)
    orbslam3_load_timeout_s: float = within(180.0, 0.0, 100_000.0, lo_open=True)
    orbslam3_frame_timeout_s: float = within(2.0, 0.0, 10_000.0, lo_open=True)
    # Repeated runs read frames decoded once (and people removed once) from a frame store in this folder (memory-
    # backed; the run's work folder when it lacks room), at most this many MB (RGB + float32 depth: 2.1 MB a
    # 640x480 frame); beyond it each run decodes its frames (docs/orbslam3_baseline.md: per-run overhead).
    orbslam3_frame_store_dir: str = text("/dev/shm", "a folder (memory-backed)")
    orbslam3_frame_store_mb: int = within(2048, 0, 10_000_000)


@dataclass(frozen=True)
class MaskingConfig(Checked):
    # `orbslam3-masked` (d2slam.baselines.masking): the person masks (the union of a frame's instances) are grown by
    # dilate_px pixels (elliptic kernel), then the depth there is set to 0 (invalid) and the RGB there is filled.
    # See docs/masking.md for the measurements behind the choice.
    dilate_px: int = within(4, 0, 1000)
    # RGB fill: "black" (0), "mean" (the frame's mean colour outside the region), "blur" (normalised convolution of
    # the pixels outside the region, Gaussian of sigma blur_px / 3 at 1/4 resolution; the mean colour where none is
    # within reach), "pushpull" (a Gaussian pyramid of the pixels outside, pushpull_levels deep, filled coarse to
    # fine), "telea" / "ns" (OpenCV inpainting, cv2.INPAINT_TELEA / cv2.INPAINT_NS, with inpaint_radius px at
    # 1/inpaint_scale of the resolution).
    fill: str = one_of("pushpull", *MASK_FILLS)
    blur_px: int = within(31, 1, 1000)
    pushpull_levels: int = within(6, 1, 20)
    inpaint_radius: float = within(3.0, 0.0, 1000.0, lo_open=True)
    inpaint_scale: int = within(8, 1, 64)
    # The blur, pushpull and inpainting fills are computed on the region's bounding box grown by this many pixels.
    crop_margin_px: int = within(32, 0, 10_000)
    # `d2slam bench masking`: a keypoint is on the boundary when within this many pixels of the filled region's edge.
    boundary_band_px: int = within(3, 0, 1000)


@dataclass(frozen=True)
class MaskedFramesConfig(Checked):
    """What ``orbslam3-masked``'s frames are made with (the person masks, then the fill): the sections of a whole
    config that the ORB-SLAM3 worker reads (``d2slam.baselines._orbslam3_worker``)."""

    segmentation: SegmentationConfig = section(SegmentationConfig)
    masking: MaskingConfig = section(MaskingConfig)
