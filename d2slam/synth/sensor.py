"""Kinect-like sensor model: depth noise, quantisation and holes; RGB motion blur and noise.

Depth (``SynthConfig``, the camera's noise and depth factor): ``z_noisy = z + sigma(z) n``, ``n ~ N(0, 1)`` at each
pixel, correlated between neighbours over ``depth_noise_corr_px`` (a structured-light sensor matches a window), with
the camera's ``sigma(z) = a + b (z - c)^2`` metres (``Camera.depth_noise``: Kinect axial noise, ~1.2 mm at 0.4 m,
~2 mm at 1 m, ~13 mm at 3 m), stored as a 16-bit PNG of ``round(z_noisy * depth_factor)`` (1/5000 m steps).
Holes (value 0): beyond ``depth_max``; at depth edges (a jump of more than ``hole_edge_jump_a + hole_edge_jump_b z``
metres inside a 3x3 window, dilated, each pixel dropped with probability ``hole_edge_prob``); random small blobs
covering ``hole_blob_fraction`` of the image. All randomness comes from the generator passed in.
"""

from __future__ import annotations

import cv2
import numpy as np

from d2slam.data.base import Camera
from d2slam.synth.config import SYNTH_CAMERA, SynthConfig


def depth_holes(z: np.ndarray, rng: np.random.Generator, cfg: SynthConfig) -> tuple[np.ndarray, np.ndarray,
                                                                                      np.ndarray]:
    """Boolean hole masks (far, edge, blob) for a clean depth map z (float32 metres, 0 = nothing)."""
    H, W = z.shape
    far = z > cfg.depth_max
    # depth edges: local max - local min over 3x3 above a depth-dependent jump
    zz = np.where(z > 0, z, np.float32(cfg.depth_max * 2)).astype(np.float32, copy=False)
    k = np.ones((3, 3), np.uint8)
    jump = cv2.dilate(zz, k)
    jump -= cv2.erode(zz, k)
    edge = (jump > cfg.hole_edge_jump_a + cfg.hole_edge_jump_b * zz).view(np.uint8)
    if cfg.hole_edge_dilate > 0:
        edge = cv2.dilate(edge, np.ones((2 * cfg.hole_edge_dilate + 1,) * 2, np.uint8))
    edge = (edge != 0) & (rng.random((H, W), dtype=np.float32) < cfg.hole_edge_prob)
    # random small blobs: a coarse uniform field, upsampled, thresholded at its own quantile
    blob = np.zeros((H, W), bool)
    if cfg.hole_blob_fraction > 0:
        cell = max(int(cfg.hole_blob_cell), 2)
        coarse = rng.random((H // cell + 2, W // cell + 2), dtype=np.float32)
        up = cv2.resize(coarse, (W + 2 * cell, H + 2 * cell), interpolation=cv2.INTER_CUBIC)[cell:cell + H,
                                                                                              cell:cell + W]
        kth = int(cfg.hole_blob_fraction * H * W)
        if kth > 0:
            blob = up < kth_smallest(up, kth)
    return far, edge, blob


def kth_smallest(a: np.ndarray, k: int) -> float:
    """The value ``np.partition(a.ravel(), k)[k]`` (0-based), partitioning only the values below a bound taken from
    a strided sample when at least k + 1 of them are below it (else the whole array)."""
    flat = a.ravel()
    n = flat.size
    if n > 64 * (k + 1):
        sample = flat[::16]
        j = min(len(sample) - 1, 2 * (k + 1) * len(sample) // n + 8)
        below = flat[flat <= np.partition(sample, j)[j]]
        if below.size > k:
            return below[np.argpartition(below, k)[k]]
    return np.partition(flat, k)[k]


def correlated_noise(white: np.ndarray, corr_px: float) -> np.ndarray:
    """Unit-variance white noise smoothed by a Gaussian of ``corr_px`` pixels and rescaled to unit variance again
    (the 2-D kernel's sum of squares is the square of the 1-D one's); unchanged when ``corr_px`` is 0."""
    if corr_px <= 0:
        return white
    k = cv2.getGaussianKernel(2 * int(np.ceil(3 * corr_px)) + 1, corr_px)
    gain = np.float32(1.0 / float((k ** 2).sum()))  # 1 / std of the smoothed field
    return cv2.sepFilter2D(white, -1, k, k, borderType=cv2.BORDER_REFLECT) * gain


def depth_to_png(z: np.ndarray, rng: np.random.Generator, cfg: SynthConfig | None = None,
                 holes: bool = True, camera: Camera = SYNTH_CAMERA) -> np.ndarray:
    """Clean depth (float32 m, 0 = nothing) -> noisy, quantised, holed uint16 image (value = metres x the
    ``camera``'s depth factor; its depth noise)."""
    cfg = cfg or SynthConfig()
    noise = camera.depth_noise
    z = np.asarray(z, np.float32)
    sigma = z - np.float32(noise.c)
    np.square(sigma, out=sigma)
    sigma *= np.float32(noise.b)
    sigma += np.float32(noise.a)
    zn = correlated_noise(rng.standard_normal(z.shape, dtype=np.float32), cfg.depth_noise_corr_px)
    zn *= sigma
    zn += z
    zn *= np.float32(camera.depth_factor)
    np.rint(zn, out=zn)
    out = np.clip(zn, 0, 65535, out=zn).astype(np.uint16)
    hole = z <= 0
    if holes:
        far, edge, blob = depth_holes(z, rng, cfg)
        hole |= far
        hole |= edge
        hole |= blob
    out[hole] = 0
    return out


def motion_blur_kernel(dx: float, dy: float, max_px: float) -> np.ndarray | None:
    """Normalised linear blur kernel for an image displacement (dx, dy) pixels over the exposure (None if < 1 px)."""
    length = float(np.hypot(dx, dy))
    if length < 1.0:
        return None
    scale = min(1.0, max_px / length)
    dx, dy = dx * scale, dy * scale
    r = int(np.ceil(max(abs(dx), abs(dy)) / 2)) + 1
    k = np.zeros((2 * r + 1, 2 * r + 1), np.float32)
    p0 = (int(round(r * 16 - dx * 8)), int(round(r * 16 - dy * 8)))
    p1 = (int(round(r * 16 + dx * 8)), int(round(r * 16 + dy * 8)))
    cv2.line(k, p0, p1, 1.0, 1, cv2.LINE_AA, 4)
    return k / k.sum()


class NoiseBank:
    """Pre-drawn integer Gaussian noise ``round(N(0, sigma))`` split into saturating uint8 (+, -) parts; a frame
    takes a slice at a random offset (from the frame's generator). Adding it with ``cv2.add`` / ``cv2.subtract``
    avoids drawing 921,600 normals per frame (measured: docs/deviations.md, ``SynthConfig.rgb_noise_sigma``)."""

    def __init__(self, size: int, sigma: float, seed: int):
        n = np.rint(np.random.default_rng([seed, 99]).standard_normal(2 * size, dtype=np.float32) * sigma)
        self.size = size
        self.pos = np.clip(n, 0, 255).astype(np.uint8)
        self.neg = np.clip(-n, 0, 255).astype(np.uint8)

    def add(self, img: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        n = img.size
        if n > self.size:
            raise ValueError("noise bank smaller than the image")
        off = int(rng.integers(0, self.size + 1))
        pos = self.pos[off:off + n].reshape(img.shape)
        neg = self.neg[off:off + n].reshape(img.shape)
        return cv2.subtract(cv2.add(img, pos), neg)


_BANKS: dict = {}


def rgb_sensor(rgb: np.ndarray, blur: tuple[float, float], rng: np.random.Generator,
               cfg: SynthConfig | None = None, bank_seed: int = 0) -> np.ndarray:
    """Mild motion blur along the camera-induced image motion ``blur`` (px over the exposure) + Gaussian noise of
    ``rgb_noise_sigma`` grey levels (rounded to integers, saturated to [0, 255])."""
    cfg = cfg or SynthConfig()
    k = motion_blur_kernel(blur[0], blur[1], cfg.blur_max_px)
    img = cv2.filter2D(rgb, -1, k, borderType=cv2.BORDER_REPLICATE) if k is not None else rgb
    if cfg.rgb_noise_sigma > 0:
        key = (img.size, float(cfg.rgb_noise_sigma), int(bank_seed))
        if key not in _BANKS:
            _BANKS.clear()
            _BANKS[key] = NoiseBank(img.size, cfg.rgb_noise_sigma, bank_seed)
        img = _BANKS[key].add(np.ascontiguousarray(img), rng)
    return img
