"""How much of a frame people cover and how many of the engine's ORB keypoints fall on them.

These two statistics are the measured basis for the synthetic people (``d2slam bench realism``): a person who is
much more feature-rich than the room makes any dynamic-SLAM method look worse than on real data (removing the
person's keypoints leaves too few for tracking), a textureless person tests nothing. Per frame:

- ``area``: fraction of the image covered by the mask (people; for synthetic frames also "dynamic" = people plus
  moved objects while they move);
- ``kp``: fraction of the engine's keypoints (``d2slam.slam.frame.OrbExtractor``: ORB-SLAM settings, bucketing)
  whose pixel lies in the mask;
- ``ratio = kp / area`` (1 = a person is as feature-rich as the rest of the frame), defined for frames where the
  mask covers at least ``MIN_AREA`` of the image.

Synthetic frames are rendered in memory by the generator's own ``render_frame`` (the same pixels as the PNGs that
``d2slam synth`` writes), so sampling a few frames of a long sequence costs no disk and no full generation.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from d2slam.data.base import RGBDFrame
from d2slam.errors import D2SlamError
from d2slam.ranges import AnyConfig, part_of
from d2slam.segmentation import get_segmenter
from d2slam.slam.config import EngineConfig, OrbConfig
from d2slam.slam.frame import OrbExtractor
from d2slam.synth.config import SYNTH_CAMERA, SynthConfig, SynthEvalConfig
from d2slam.synth.generate import render_frame
from d2slam.synth.scene import Scene
from d2slam.synth.world import WorldRenderer

MIN_AREA = 0.05  # frames with less mask than this (a sliver at the border) have no meaningful ratio


@dataclass
class FrameStats:
    """Per-frame statistics of one source (arrays over the sampled frames)."""

    name: str
    frames: np.ndarray  # frame indices (synthetic) or 0..n-1 (real images)
    area: np.ndarray  # person area fraction
    kp: np.ndarray  # fraction of keypoints on persons
    n_kp: np.ndarray  # keypoints per frame
    textured: np.ndarray | None = None  # share of textured pixels (``texture_stats``)
    corners: np.ndarray | None = None  # FAST corners per frame (``texture_stats``)
    dyn_area: np.ndarray | None = None  # synthetic only: persons + moving objects
    dyn_kp: np.ndarray | None = None

    @property
    def ratio(self) -> np.ndarray:
        return ratio(self.kp, self.area)

    @property
    def dyn_ratio(self) -> np.ndarray | None:
        return None if self.dyn_area is None else ratio(self.dyn_kp, self.dyn_area)


def ratio(kp: np.ndarray, area: np.ndarray) -> np.ndarray:
    """kp / area over the frames whose area is at least ``MIN_AREA`` (others dropped)."""
    kp, area = np.asarray(kp, float), np.asarray(area, float)
    ok = area >= MIN_AREA
    return kp[ok] / area[ok]


def extractor(camera=None, config: AnyConfig | None = None):
    """The engine's ORB extractor (ORB-SLAM settings) for ``camera`` (default the synthetic one, freiburg3's)."""
    camera = camera or SYNTH_CAMERA
    return OrbExtractor(part_of(config, "orb", OrbConfig), part_of(config, "engine", EngineConfig), camera)


def keypoints_on(kps: np.ndarray, masks: list[np.ndarray]) -> list[float]:
    """Fraction of keypoints (N, 2) pixel coordinates whose rounded pixel lies in each (H, W) bool mask."""
    if len(kps) == 0:
        return [0.0 for _ in masks]
    h, w = masks[0].shape
    u = np.clip(np.round(kps[:, 0]).astype(np.int64), 0, w - 1)
    v = np.clip(np.round(kps[:, 1]).astype(np.int64), 0, h - 1)
    return [float(m[v, u].mean()) for m in masks]


def frame_stats(gray: np.ndarray, depth: np.ndarray, masks: list[np.ndarray], ext) -> tuple[list, list, int]:
    """(areas, keypoint fractions, number of keypoints) of one frame for each mask."""
    fr = ext(gray, depth)
    kps = fr.kps_raw if fr.n else np.zeros((0, 2))
    return [float(m.mean()) for m in masks], keypoints_on(kps, masks), int(fr.n)


def texture_stats(gray: np.ndarray, cfg: SynthEvalConfig) -> tuple[float, int]:
    """(share of textured pixels, FAST corners) of a grey image: a pixel is textured when the standard deviation of
    its ``realism_window``-square neighbourhood exceeds ``realism_texture_sd`` grey levels; corners are FAST at
    ``realism_fast_threshold`` (ORB-SLAM's initial threshold), not capped like the extractor's keypoints."""
    g = gray.astype(np.float32)
    k = (int(cfg.realism_window),) * 2
    m = cv2.blur(g, k)
    var = cv2.blur(g * g, k) - m * m
    share = float((var > np.float32(cfg.realism_texture_sd) ** 2).mean())
    fast = cv2.FastFeatureDetector_create(threshold=int(cfg.realism_fast_threshold))
    return share, len(fast.detect(gray))


def sample_indices(frames: int, stride: int) -> np.ndarray:
    if stride < 1:
        raise D2SlamError(f"--stride must be at least 1 (got {stride})")
    return np.arange(0, int(frames), int(stride))


def synthetic_stats(scenario: str, seed: int = 101, frames: int = 300, stride: int = 10,
                    cfg: SynthConfig | None = None, config: AnyConfig | None = None, ext=None) -> FrameStats:
    """Person / dynamic statistics of every ``stride``-th frame of a synthetic sequence (rendered in memory)."""

    cfg = cfg or part_of(config, "synth", SynthConfig)
    scene = Scene(scenario, seed, frames, False, cfg)
    renderer = WorldRenderer(scene)
    ext = ext or extractor(config=config)
    idx = sample_indices(frames, stride)
    person_lut = np.zeros(256, bool)
    person_lut[scene.person_ids] = True
    rows = []
    for i in idx:
        f = render_frame(scene, renderer, int(i))
        t = float(scene.t_rel[i])
        dyn_lut = person_lut.copy()
        dyn_lut[[o.oid for o in scene.objects if o.moving(t)]] = True
        masks = [person_lut[f["mask_gt"]], dyn_lut[f["mask_gt"]]]
        gray = cv2.cvtColor(f["rgb"], cv2.COLOR_RGB2GRAY)
        areas, kps, n = frame_stats(gray, f["depth"].astype(np.float32) / scene.intrinsics.depth_factor, masks, ext)
        texture = texture_stats(gray, part_of(config, "synth_eval", SynthEvalConfig))
        rows.append((areas[0], kps[0], n, areas[1], kps[1], *texture))
    renderer.close()
    a = np.array(rows, float).reshape(-1, 7)
    return FrameStats(f"{scenario} seed {seed}", idx, a[:, 0], a[:, 1], a[:, 2].astype(int), dyn_area=a[:, 3],
                      dyn_kp=a[:, 4], textured=a[:, 5], corners=a[:, 6].astype(int))


def real_stats(paths: list[Path], segmenter=None, config: AnyConfig | None = None, ext=None) -> FrameStats:
    """Person statistics of real RGB frames (no depth needed), persons from ``segmenter`` (default: ONNX)."""
    if not paths:
        raise D2SlamError("no real frames to measure")
    if segmenter is None:
        segmenter = get_segmenter("onnx", config=config)
    ext = ext or extractor(config=config)
    rows = []
    for p in paths:
        bgr = cv2.imread(str(p), cv2.IMREAD_COLOR)
        if bgr is None:
            raise D2SlamError("image cannot be decoded", path=p)
        rgb = cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
        depth = np.zeros(rgb.shape[:2], np.float32)  # keypoint positions do not depend on depth
        frame = RGBDFrame(0, 0.0, 0.0, rgb, depth, rgb_path=Path(p))
        mask = np.zeros(rgb.shape[:2], bool)
        for inst in segmenter(frame):
            mask |= inst.mask
        gray = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
        areas, kps, n = frame_stats(gray, depth, [mask], ext)
        rows.append((areas[0], kps[0], n, *texture_stats(gray, part_of(config, "synth_eval", SynthEvalConfig))))
    a = np.array(rows, float)
    return FrameStats("TUM fr3 (real, ONNX masks)", np.arange(len(paths)), a[:, 0], a[:, 1], a[:, 2].astype(int),
                      textured=a[:, 3], corners=a[:, 4].astype(int))


def summary(values: np.ndarray) -> tuple[float, float, float]:
    """(mean, min, max); NaNs for no values."""
    v = np.asarray(values, float)
    if v.size == 0:
        return (float("nan"),) * 3
    return float(v.mean()), float(v.min()), float(v.max())
