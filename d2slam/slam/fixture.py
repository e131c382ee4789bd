"""A tiny analytic RGB-D world for engine tests: the camera moves inside a textured box room (ray-plane
intersection per pixel, texture lookup by ``cv2.remap``), with exact depth. Independent of the synthetic benchmark
generator so the engine can be unit-tested on its own."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from d2slam.data.base import Camera, Trajectory
from d2slam.data.intrinsics import FREIBURG3
from d2slam.data.tum import write_tum_trajectory

FR3 = FREIBURG3


def _texture(rng: np.random.Generator, size: int = 512) -> np.ndarray:
    """Multi-scale blob texture with sharp edges (rich in ORB corners)."""
    img = np.zeros((size, size), np.float32)
    for s in (4, 8, 16, 32):
        n = rng.random((size // s, size // s)).astype(np.float32)
        img += cv2.resize(n, (size, size), interpolation=cv2.INTER_NEAREST if s >= 16 else cv2.INTER_LINEAR) / s
    img = cv2.normalize(img, None, 0, 255, cv2.NORM_MINMAX)
    for _ in range(size // 4):  # rectangles and circles: strong corners
        c = tuple(int(x) for x in rng.integers(0, size, 2))
        col = int(rng.integers(0, 255))
        if rng.random() < 0.5:
            cv2.rectangle(img, c, (c[0] + int(rng.integers(8, 60)), c[1] + int(rng.integers(8, 60))), col, -1)
        else:
            cv2.circle(img, c, int(rng.integers(4, 30)), col, -1)
    return img.astype(np.uint8)


class BoxRoom:
    """Axis-aligned room ``[-hx, hx] x [-hy, hy] x [-hz, hz]`` (metres), one texture per face."""

    def __init__(self, seed: int = 0, half=(2.0, 1.2, 2.0), texture_px: int = 1024):
        rng = np.random.default_rng(seed)
        self.half = np.asarray(half, float)
        self.textures = [_texture(rng, texture_px) for _ in range(6)]

    def render(self, Twc: np.ndarray, camera: Camera = FR3) -> tuple[np.ndarray, np.ndarray]:
        """(gray uint8 (H, W), depth float32 metres (H, W)) seen from camera pose ``Twc``."""
        h, w = camera.height, camera.width
        u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
        d_c = np.stack([(u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy, np.ones_like(u)], -1)
        d_w = d_c @ Twc[:3, :3].T
        o = Twc[:3, 3]
        best_t = np.full((h, w), np.inf)
        face = np.full((h, w), -1)
        with np.errstate(divide="ignore", invalid="ignore"):
            for axis in range(3):
                for sgn in (-1, 1):
                    t = (sgn * self.half[axis] - o[axis]) / d_w[..., axis]
                    ok = (t > 0) & (t < best_t)
                    best_t = np.where(ok, t, best_t)
                    face = np.where(ok, 2 * axis + (sgn > 0), face)
        P = o + d_w * best_t[..., None]
        gray = np.zeros((h, w), np.uint8)
        for f in range(6):
            axis = f // 2
            a, b = [i for i in range(3) if i != axis]
            tex = self.textures[f]
            n = tex.shape[0]
            mx = ((P[..., a] / self.half[a] + 1.0) * 0.5 * (n - 1)).astype(np.float32)  # one texture per face,
            my = ((P[..., b] / self.half[b] + 1.0) * 0.5 * (n - 1)).astype(np.float32)  # no repetition
            img = cv2.remap(tex, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP)
            gray = np.where(face == f, img, gray)
        depth = (best_t * 1.0).astype(np.float32)  # d_c has z = 1, so t is the camera-frame depth
        return gray, depth


def circle_trajectory(n: int, fps: float = 30.0, radius: float = 0.3, yaw_amp: float = 0.25) -> np.ndarray:
    """(n, 4, 4) T_world_camera: the camera translates on a small circle and yaws gently, looking along +z."""
    t = np.arange(n) / fps
    poses = np.tile(np.eye(4), (n, 1, 1))
    ang = 2 * np.pi * t / 6.0
    poses[:, 0, 3] = radius * np.sin(ang)
    poses[:, 1, 3] = 0.1 * np.sin(2 * ang)
    poses[:, 2, 3] = radius * (np.cos(ang) - 1) - 0.5
    rv = np.stack([0.05 * np.sin(ang), yaw_amp * np.sin(ang), 0.03 * np.cos(ang)], 1)
    poses[:, :3, :3] = Rotation.from_rotvec(rv).as_matrix()
    return poses


def room_sequence(n: int = 30, seed: int = 0, fps: float = 30.0):
    """Frames (gray, depth), ground-truth poses and timestamps of a camera moving in a :class:`BoxRoom`."""
    room = BoxRoom(seed)
    poses = circle_trajectory(n, fps)
    frames = [room.render(T) for T in poses]
    ts = 1000.0 + np.arange(n) / fps
    return frames, poses, ts


def write_room_sequence(root, n: int = 30, seed: int = 0, fps: float = 30.0) -> "Path":
    """Write a :func:`room_sequence` as a TUM folder (rgb/, depth/ x5000, rgb.txt, depth.txt, groundtruth.txt)."""
    root = Path(root)
    (root / "rgb").mkdir(parents=True, exist_ok=True)
    (root / "depth").mkdir(parents=True, exist_ok=True)
    frames, poses, ts = room_sequence(n, seed, fps)
    rgb_lines, depth_lines = ["# color images"], ["# depth maps"]
    for (gray, depth), t in zip(frames, ts):
        name = f"{t:.6f}.png"
        cv2.imwrite(str(root / "rgb" / name), cv2.cvtColor(gray, cv2.COLOR_GRAY2BGR))
        d16 = np.clip(np.rint(depth * 5000.0), 0, 65535).astype(np.uint16)
        cv2.imwrite(str(root / "depth" / name), d16)
        rgb_lines.append(f"{t:.6f} rgb/{name}")
        depth_lines.append(f"{t:.6f} depth/{name}")
    (root / "rgb.txt").write_text("\n".join(rgb_lines) + "\n")
    (root / "depth.txt").write_text("\n".join(depth_lines) + "\n")
    write_tum_trajectory(root / "groundtruth.txt", Trajectory(ts, poses))
    return root
