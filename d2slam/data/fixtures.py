"""Tiny TUM folders written on the fly, for tests and examples (no real TUM data is reachable here).

``write_tum_folder`` writes a valid sequence in the exact TUM layout with known content: RGB frames whose pixels
encode the frame index, 16-bit depth with a known value pattern (including 0 = invalid), depth timestamps a few
ms after the RGB ones, and 100 Hz ground truth from an analytic motion (:func:`analytic_pose`), so readers can be
checked against exact values.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

T0 = 1305031102.0  # a TUM-like epoch timestamp (s)


def analytic_pose(t: np.ndarray, t0: float = T0) -> np.ndarray:
    """T_world_camera (N, 4, 4) of the fixture motion: yaw 0.5 rad/s about z and translation (0.1 s, -0.05 s,
    0.02 s) metres with s = t - t0. Linear translation and a constant-axis rotation, so linear + SLERP
    interpolation between any two samples is exact."""
    s = np.atleast_1d(np.asarray(t, dtype=np.float64)) - t0
    poses = np.tile(np.eye(4), (len(s), 1, 1))
    poses[:, :3, :3] = Rotation.from_rotvec(np.outer(0.5 * s, [0.0, 0.0, 1.0])).as_matrix()
    poses[:, :3, 3] = np.outer(s, [0.1, -0.05, 0.02])
    return poses


def depth_pattern(index: int, height: int, width: int) -> np.ndarray:
    """uint16 depth of frame ``index``: 5000 + 10 * index + column (so 1.0 m + ...), with a 0 (invalid) first
    row."""
    d = (5000 + 10 * index + np.arange(width, dtype=np.uint16))[None, :].repeat(height, axis=0)
    d[0, :] = 0
    return d.astype(np.uint16)


def rgb_pattern(index: int, height: int, width: int) -> np.ndarray:
    """uint8 RGB of frame ``index``: R = index, G = column mod 256, B = 200."""
    img = np.zeros((height, width, 3), dtype=np.uint8)
    img[..., 0] = index % 256
    img[..., 1] = (np.arange(width) % 256)[None, :]
    img[..., 2] = 200
    return img


def write_tum_folder(root: str | Path, n_frames: int = 5, width: int = 64, height: int = 48, fps: float = 30.0,
                     depth_lag: float = 0.004, gt_rate: float = 100.0, t0: float = T0,
                     with_groundtruth: bool = True) -> dict:
    """Write a TUM folder at ``root`` (created). Returns ``{"rgb_ts", "depth_ts", "gt_ts", "root"}``."""
    root = Path(root)
    (root / "rgb").mkdir(parents=True, exist_ok=True)
    (root / "depth").mkdir(parents=True, exist_ok=True)
    as_written = np.vectorize(lambda t: float(f"{t:.6f}"), otypes=[np.float64])  # the values in the files
    rgb_ts = as_written(t0 + 0.05 + np.arange(n_frames) / fps) if n_frames else np.zeros(0)
    depth_ts = as_written(rgb_ts + depth_lag) if n_frames else np.zeros(0)
    rgb_lines = ["# color images", "# file: 'fixture'", "# timestamp filename"]
    depth_lines = ["# depth maps", "# file: 'fixture'", "# timestamp filename"]
    for i, (tr, td) in enumerate(zip(rgb_ts, depth_ts)):
        name_r, name_d = f"rgb/{tr:.6f}.png", f"depth/{td:.6f}.png"
        cv2.imwrite(str(root / name_r), cv2.cvtColor(rgb_pattern(i, height, width), cv2.COLOR_RGB2BGR))
        cv2.imwrite(str(root / name_d), depth_pattern(i, height, width))
        rgb_lines.append(f"{tr:.6f} {name_r}")
        depth_lines.append(f"{td:.6f} {name_d}")
    (root / "rgb.txt").write_text("\n".join(rgb_lines) + "\n")
    (root / "depth.txt").write_text("\n".join(depth_lines) + "\n")
    gt_ts = np.arange(t0, rgb_ts[-1] + 0.1, 1.0 / gt_rate) if n_frames else np.zeros(0)
    if with_groundtruth:
        poses = analytic_pose(gt_ts, t0)
        quat = Rotation.from_matrix(poses[:, :3, :3]).as_quat()
        lines = ["# ground truth trajectory", "# file: 'fixture'", "# timestamp tx ty tz qx qy qz qw"]
        lines += [f"{t:.4f} " + " ".join(f"{v:.9f}" for v in np.r_[p[:3, 3], q])
                  for t, p, q in zip(gt_ts, poses, quat)]
        (root / "groundtruth.txt").write_text("\n".join(lines) + "\n")
    return {"root": root, "rgb_ts": rgb_ts, "depth_ts": depth_ts, "gt_ts": gt_ts}


def recording_folder(root: str | Path, frames: int = 6) -> Path:
    """``root/rgbd_dataset_freiburg1_fake``: a TUM folder of a real recording as the synthetic twin reads it
    (``d2slam.synth.twin.read_recording``): ``frames`` (at most 6) RGB and depth entries, the depth 4-9 ms after each
    RGB, and a turning, moving 100 Hz ground truth (z up, the camera 1.55 m high looking about 35 degrees down, like
    fr1/rpy's). The images are empty placeholders: the twin reads only the lists and the ground truth."""
    seq = Path(root) / "rgbd_dataset_freiburg1_fake"
    for d in ("rgb", "depth"):
        (seq / d).mkdir(parents=True)
    t0 = 1305031229.5
    ts = t0 + np.arange(frames) * 0.032 + np.array([0.0, 0.0013, -0.0008, 0.0021, 0.0, 0.001][:frames])
    dts = ts + np.linspace(0.004, 0.009, frames)
    rgb = "".join(f"{t:.6f} rgb/{t:.6f}.png\n" for t in ts)
    dep = "".join(f"{t:.6f} depth/{t:.6f}.png\n" for t in dts)
    for t in ts:
        (seq / "rgb" / f"{t:.6f}.png").write_bytes(b"")
    for t in dts:
        (seq / "depth" / f"{t:.6f}.png").write_bytes(b"")
    (seq / "rgb.txt").write_text("# color images\n# timestamp filename\n" + rgb)
    (seq / "depth.txt").write_text("# depth maps\n# timestamp filename\n" + dep)
    g = np.arange(np.floor((t0 - 1.0) * 100), np.ceil((ts[-1] + 1.0) * 100) + 1) / 100
    s = g - t0
    rot = Rotation.from_euler("ZYX", np.stack([2.0 + 0.8 * s, 0.1 * np.sin(3 * s), np.zeros_like(s)], 1)) \
        * Rotation.from_euler("x", -np.pi / 2 - 0.6)  # optical axis forward and 35 degrees down, z up
    q = rot.as_quat()
    pos = np.stack([1.3 + 0.05 * s, 0.6 + 0.02 * s, np.full_like(s, 1.55)], 1)
    (seq / "groundtruth.txt").write_text("# ground truth trajectory\n# timestamp tx ty tz qx qy qz qw\n" + "".join(
        f"{t:.4f} " + " ".join(f"{v:.6f}" for v in p) + " " + " ".join(f"{v:.7f}" for v in qq) + "\n"
        for t, p, qq in zip(g, pos, q)))
    return seq
