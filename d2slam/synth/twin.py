"""The synthetic twin of a real recording: our office, static (no people), along the recording's ground truth, at
its frame and depth times, through its camera, seen by a sensor calibrated against it (``SynthConfig.twin``,
``TwinConfig``; the measurements: docs/real_data.md, "The synthetic twin and the sensor model").

``d2slam synth fr1_rpy_twin --on-trajectory TUM_DIR --out DIR`` (the recording is an input: it is not in git):

- **Times**: the recording's associated RGB-D frames (TUM's association of its ``rgb.txt`` and ``depth.txt``): the
  twin's RGB images carry the real RGB timestamps and its depth images the real depth timestamps.
- **Path**: the recording's ground truth, interpolated at each instant (linear position, SLERP rotation, bridging the
  motion capture's short dropouts), placed in the room by one rigid motion about the vertical (:func:`placement`:
  the first pose's optical centre at ``anchor_xy``, its heading ``anchor_heading_deg``). ``groundtruth.txt`` is the
  recording's ground truth samples so placed, over the frames plus ``gt_margin``.
- **Camera**: the recording's (from the folder name: freiburg1 for fr1/rpy), with its lens distortion: every image is
  rendered through a pinhole camera of the same focal lengths and then distorted (:class:`LensMap`, ``cv2.remap``;
  the pinhole canvas grows when the distorted image sees beyond it), so the camera model's undistortion gives the
  pinhole geometry back.
- **RGB**: the exposure's image: the average of sub-frames rendered at instants spread over the exposure (and, with a
  rolling shutter, each row over its own window), ``rgb_time_shift`` after the timestamp; then the sensor noise of
  ``d2slam.synth.sensor.rgb_sensor``.
- **Depth**: rendered at the depth image's instant (its timestamp plus ``depth_time_shift``: misregistered with the
  colour by the motion in between, ``depth_at_depth_time``), distorted, the Kinect model of
  ``d2slam.synth.sensor.depth_to_png``, the projector's shadows (:func:`shadow_holes`) and the border the registered
  depth does not cover (``depth_border``).

Deterministic: each frame's noise comes from generators seeded with (seed, scenario, frame index, stream), as for the
other scenarios.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from d2slam.data.base import Camera
from d2slam.data.tum import TumSequence, interpolate_poses
from d2slam.errors import D2SlamError
from d2slam.synth.config import SynthConfig
from d2slam.synth.rigid import pose_rows
from d2slam.synth.segsim import simulate_segmenter
from d2slam.synth.sensor import depth_to_png, rgb_sensor


# --------------------------------------------------------------------------------------------------
# the recording
# --------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Recording:
    """What the twin takes from a real TUM recording: its camera, associated frame times and ground truth."""

    name: str
    camera: Camera
    rgb_times: np.ndarray  # (N,) RGB timestamps of the associated frames
    depth_times: np.ndarray  # (N,) their depth images' timestamps
    gt_times: np.ndarray  # (M,) ground truth timestamps
    gt_poses: np.ndarray  # (M, 4, 4) T_world_camera in the recording's world (Z up)
    root: Path | None = None  # its folder
    frame_index: np.ndarray | None = None  # (N,) each frame's index among the folder's associated frames

    def __len__(self) -> int:
        return len(self.rgb_times)

    def part(self, first: int, frames: int) -> "Recording":
        """The recording's frames ``first`` .. ``first + frames - 1`` (its ground truth whole)."""
        if not 0 <= int(first) < len(self) or int(frames) < 1:
            raise D2SlamError(f"frames {first} to {int(first) + int(frames) - 1} are not in the recording's "
                              f"{len(self)} frames", path=self.root)
        cut = slice(int(first), int(first) + int(frames))
        index = None if self.frame_index is None else self.frame_index[cut]
        return dataclasses.replace(self, rgb_times=self.rgb_times[cut], depth_times=self.depth_times[cut],
                                   frame_index=index)


def read_recording(path: str | Path) -> Recording:
    """A TUM folder (``rgb.txt``, ``depth.txt``, ``groundtruth.txt``; the camera from its name) as a
    :class:`Recording`; frames outside the ground truth's span are left out (the twin needs a pose for each)."""
    seq = TumSequence(path)
    gt = seq.groundtruth
    if gt is None or len(gt) < 2:
        raise D2SlamError("the recording has no ground truth (groundtruth.txt): the twin follows it", path=seq.root)
    ts, dts = np.asarray(seq.timestamps, float), np.asarray(seq.depth_timestamps, float)
    inside = (ts >= gt.timestamps[0]) & (ts <= gt.timestamps[-1])
    if not inside.any():
        raise D2SlamError("no frame lies within the ground truth's time span", path=seq.root)
    return Recording(seq.name, seq.camera, ts[inside], dts[inside], np.asarray(gt.timestamps, float),
                     np.asarray(gt.poses, float), Path(seq.root), np.flatnonzero(inside))


def placement(first_pose: np.ndarray, anchor_xy: tuple[float, float], heading_deg: float) -> np.ndarray:
    """The rigid motion (4x4) about the vertical (world Z) that puts the optical centre of ``first_pose``
    (``T_world_camera``) at ``anchor_xy`` (its height kept) with its optical axis heading ``heading_deg`` (degrees
    from +x, seen from above)."""
    c0 = first_pose[:3, 3]
    axis = first_pose[:3, 2]
    if np.hypot(axis[0], axis[1]) < 1e-6:
        raise D2SlamError("the first camera pose looks straight up or down: its heading is undefined")
    phi = np.radians(heading_deg) - np.arctan2(axis[1], axis[0])
    c, s = np.cos(phi), np.sin(phi)
    A = np.eye(4)
    A[:3, :3] = [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]
    A[:3, 3] = np.array([anchor_xy[0], anchor_xy[1], c0[2]]) - A[:3, :3] @ c0
    return A


class RecordedPath:
    """The twin's camera path: ``poses(t)`` -> (N, 4, 4) ``T_world_camera`` in the room at ``t`` seconds after
    ``t0`` (the first frame's timestamp), the recording's ground truth interpolated (linear position, SLERP rotation;
    a motion-capture dropout is bridged) and placed by ``A``; times beyond the ground truth take its end poses."""

    def __init__(self, rec: Recording, A: np.ndarray, t0: float):
        self.t0 = float(t0)
        self.gt_times = rec.gt_times
        self.gt_poses = np.einsum("ij,njk->nik", A, rec.gt_poses)
        self.A = A

    def poses(self, t) -> np.ndarray:
        tt = np.clip(self.t0 + np.atleast_1d(np.asarray(t, float)), self.gt_times[0], self.gt_times[-1])
        return interpolate_poses(self.gt_times, self.gt_poses, tt, max_gap=None)


# --------------------------------------------------------------------------------------------------
# the lens
# --------------------------------------------------------------------------------------------------
def distort_normalised(x: np.ndarray, dist) -> np.ndarray:
    """OpenCV's lens model (k1, k2, p1, p2, k3) on normalised image coordinates (N, 2): what ``cv2.projectPoints``
    applies between the pinhole projection and the intrinsics."""
    k1, k2, p1, p2, k3 = (float(v) for v in dist)
    x = np.asarray(x, np.float64)
    u, v = x[..., 0], x[..., 1]
    r2 = u * u + v * v
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    return np.stack([u * radial + 2 * p1 * u * v + p2 * (r2 + 2 * u * u),
                     v * radial + p1 * (r2 + 2 * v * v) + 2 * p2 * u * v], axis=-1)


def undistort_normalised(xd: np.ndarray, dist, iterations: int = 12) -> np.ndarray:
    """The inverse of :func:`distort_normalised` by Newton's method (Jacobian by central differences), started at
    the distorted point; converged to far below a thousandth of a pixel within the image of a real camera."""
    xd = np.asarray(xd, np.float64)
    x = xd.copy()
    h = 1e-7
    for _ in range(iterations):
        f = distort_normalised(x, dist) - xd
        ju = (distort_normalised(x + [h, 0.0], dist) - distort_normalised(x - [h, 0.0], dist)) / (2 * h)
        jv = (distort_normalised(x + [0.0, h], dist) - distort_normalised(x - [0.0, h], dist)) / (2 * h)
        a, b, c, d = ju[..., 0], jv[..., 0], ju[..., 1], jv[..., 1]
        det = a * d - b * c
        x = x - np.stack([(d * f[..., 0] - b * f[..., 1]) / det, (a * f[..., 1] - c * f[..., 0]) / det], axis=-1)
    return x


class LensMap:
    """Distorts images rendered by a pinhole camera into the image of ``camera`` (with its lens distortion).

    ``K``, ``width``, ``height``: the pinhole canvas to render (the camera's focal lengths; grown, with the principal
    point shifted, when the distorted image sees beyond the camera's own pinhole frame). ``__call__(img, nearest)``:
    the camera's image, each pixel taken at its undistorted position in the canvas (bilinear, or nearest for depth
    and ids); outside the canvas 0. Without distortion the canvas is the camera's and the map the identity."""

    def __init__(self, camera: Camera, distortion: bool = True):
        W, H = int(camera.width), int(camera.height)
        K = camera.K
        self.camera = camera
        self.identity = not (distortion and camera.has_distortion)
        if self.identity:
            self.K, self.width, self.height = K, W, H
            self.map_x = self.map_y = None
            return
        u, v = np.meshgrid(np.arange(W, dtype=np.float64), np.arange(H, dtype=np.float64))
        xd = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1]], axis=-1)
        x = undistort_normalised(xd, camera.dist)
        pu, pv = x[..., 0] * K[0, 0] + K[0, 2], x[..., 1] * K[1, 1] + K[1, 2]
        # canvas: the camera's pinhole frame, grown by whole pixels where the undistorted image reaches beyond it
        left = int(np.ceil(max(0.0, -pu.min() + 1)))
        top = int(np.ceil(max(0.0, -pv.min() + 1)))
        right = int(np.ceil(max(0.0, pu.max() - (W - 1) + 1)))
        bottom = int(np.ceil(max(0.0, pv.max() - (H - 1) + 1)))
        self.width, self.height = W + left + right, H + top + bottom
        self.K = K.copy()
        self.K[0, 2] += left
        self.K[1, 2] += top
        self.map_x = (pu + left).astype(np.float32)
        self.map_y = (pv + top).astype(np.float32)

    def __call__(self, img: np.ndarray, nearest: bool = False) -> np.ndarray:
        if self.identity:
            return img
        return cv2.remap(img, self.map_x, self.map_y, cv2.INTER_NEAREST if nearest else cv2.INTER_LINEAR,
                         borderMode=cv2.BORDER_CONSTANT, borderValue=0)


def twin_config(cfg: SynthConfig) -> SynthConfig:
    """The twin's ``SynthConfig``: ``cfg`` with the twin's RGB noise and hole blobs (``TwinConfig.rgb_noise_sigma``,
    ``hole_blob_fraction``); its camera is the recording's (``Scene.intrinsics``)."""
    tw = cfg.twin
    return dataclasses.replace(cfg, rgb_noise_sigma=tw.rgb_noise_sigma, hole_blob_fraction=tw.hole_blob_fraction)


def shadow_holes(z: np.ndarray, cfg: SynthConfig, casters: np.ndarray | None = None) -> np.ndarray:
    """(H, W) bool: the projector's shadow of a clean depth image ``z`` (m, 0 = nothing): ``TwinConfig.shadow_px``
    pixels to the left of every depth edge whose nearer side is on the right (a step of more than ``hole_edge_jump_a
    + hole_edge_jump_b z`` between horizontal neighbours); with ``casters`` (H, W) bool, only the edges whose nearer
    pixel is one of them."""
    w = int(cfg.twin.shadow_px)
    out = np.zeros(z.shape, bool)
    if w <= 0:
        return out
    left, right = z[:, :-1], z[:, 1:]
    step = (right > 0) & (left - right > cfg.hole_edge_jump_a + cfg.hole_edge_jump_b * right)
    if casters is not None:
        step &= casters[:, 1:]
    out[:, :-1] = step
    band = cv2.dilate(out.view(np.uint8), np.ones((1, w), np.uint8), anchor=(0, 0))  # each step and w - 1 to its left
    return band.astype(bool)


# --------------------------------------------------------------------------------------------------
# one frame
# --------------------------------------------------------------------------------------------------
def row_windows(t: float, shift: float, readout: float, exposure: float,
                height: int) -> tuple[float, float, np.ndarray]:
    """(start, end, (H, 2) row windows) of an image stamped ``t`` (s from the first frame): row r is exposed over
    ``[c_r - exposure / 2, c_r + exposure / 2]`` with ``c_r = t + shift + (r - (H - 1) / 2) readout`` (a rolling
    shutter reads a row ``readout`` s after the row above it; the shifted timestamp is the middle row's instant)."""
    c = t + shift + (np.arange(height) - (height - 1) / 2.0) * readout
    win = np.stack([c - exposure / 2.0, c + exposure / 2.0], axis=1)
    return float(win[:, 0].min()), float(win[:, 1].max()), win


def subframe_count(scene, start: float, end: float, z: np.ndarray, step_px: float) -> int:
    """Sub-frames over ``[start, end]``: enough that no pixel of a 3 x 3 grid (at its rendered depth ``z``, the
    median where there is none) moves more than ``step_px`` between two, at most ``subframes_max``."""
    tw = scene.cfg.twin
    if end <= start:
        return 1
    K, H, W = scene.canvas_K, z.shape[0], z.shape[1]
    u, v = np.meshgrid(np.linspace(0, W - 1, 3), np.linspace(0, H - 1, 3))
    zz = z[v.astype(int), u.astype(int)].astype(np.float64)
    valid = zz[zz > 0]
    zz = np.where(zz > 0, zz, np.median(valid) if valid.size else 1.0)
    Xc = np.stack([(u - K[0, 2]) / K[0, 0] * zz, (v - K[1, 2]) / K[1, 1] * zz, zz], axis=-1).reshape(-1, 3)
    Ta, Tb = scene.camera.poses([start, end])
    Xw = Xc @ Ta[:3, :3].T + Ta[:3, 3]
    Xb = (Xw - Tb[:3, 3]) @ Tb[:3, :3]
    ub = K[0, 0] * Xb[:, 0] / Xb[:, 2] + K[0, 2]
    vb = K[1, 1] * Xb[:, 1] / Xb[:, 2] + K[1, 2]
    move = float(np.nanmax(np.hypot(ub - u.ravel(), vb - v.ravel())))
    return int(np.clip(np.ceil(move / step_px), 1, tw.subframes_max))


def row_weights(start: float, end: float, n: int, windows: np.ndarray) -> np.ndarray:
    """(H, n) weight of each of ``n`` equal sub-frames of ``[start, end]`` (each stands for its slice of time) in each
    row's exposure window (H, 2): the share of the window the slice covers; rows sum to 1. A window shorter than a
    slice (or empty) takes the slice it lies in."""
    edges = np.linspace(start, end, n + 1)
    lo = np.maximum(edges[None, :-1], windows[:, :1])
    hi = np.minimum(edges[None, 1:], windows[:, 1:])
    w = np.clip(hi - lo, 0.0, None)
    s = w.sum(axis=1, keepdims=True)
    point = s[:, 0] <= 0
    if point.any():
        k = np.clip(np.searchsorted(edges, windows[point].mean(axis=1)) - 1, 0, n - 1)
        w[point] = 0.0
        w[np.flatnonzero(point), k] = 1.0
        s = w.sum(axis=1, keepdims=True)
    return w / s


def subframe_times(start: float, end: float, n: int) -> np.ndarray:
    """The middles of ``n`` equal slices of ``[start, end]``: the sub-frames' instants."""
    return start + (np.arange(n) + 0.5) * (end - start) / n


def subframe_plan(scene, start: float, end: float, windows: np.ndarray, z: np.ndarray,
                  step_px: float, least: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """(instants (n,), (H, n) row weights) of the sub-frames that render an image whose rows are exposed over
    ``windows`` within ``[start, end]`` (:func:`subframe_count` of them at ``step_px``, at least ``least`` over a
    window of some length, :func:`row_weights`)."""
    n = subframe_count(scene, start, end, z, step_px)
    if end > start:
        n = max(n, int(least))
    return subframe_times(start, end, n), row_weights(start, end, n, windows)


def depth_rows(scene, renderer, start: float, end: float, windows: np.ndarray, at=None):
    """(depth (H, W) float32 m, ids (H, W) uint8, the canvas depth at the middle instant, sub-frames) of a depth
    image whose rows are taken over ``windows`` within ``[start, end]``: each row from the sub-frame whose slice of
    time holds it (``depth_subframe_px`` apart), through the lens. ``at(t)``: called before each render with its
    instant (a composite moves its people there)."""
    tw, lens = scene.cfg.twin, scene.lens
    H, W = int(scene.intrinsics.height), int(scene.intrinsics.width)
    mid = 0.5 * (start + end)
    if at is not None:
        at(mid)
    z, ids = renderer.gl.render_depth(scene.camera.poses([mid])[0])
    times, weights = subframe_plan(scene, start, end, windows, z, tw.depth_subframe_px)
    if len(times) == 1:
        return lens(z, nearest=True), lens(ids, nearest=True), z, 1
    pick = np.argmax(weights, axis=1)
    zd, idd = np.zeros((H, W), np.float32), np.zeros((H, W), np.uint8)
    for k, (tk, Tk) in enumerate(zip(times, scene.camera.poses(times))):
        rows = pick == k
        if rows.any():
            if at is not None:
                at(float(tk))
            zk, ik = renderer.gl.render_depth(Tk)
            zd[rows], idd[rows] = lens(zk, nearest=True)[rows], lens(ik, nearest=True)[rows]
    return zd, idd, z, len(times)


def depth_windows(scene, i: int) -> tuple[float, float, np.ndarray]:
    """:func:`row_windows` of frame ``i``'s depth image: its own instant and rolling shutter
    (``depth_at_depth_time``), else the RGB image's instant, global."""
    tw, H = scene.cfg.twin, int(scene.intrinsics.height)
    t = float(scene.t_rel[i])
    if tw.depth_at_depth_time:
        return row_windows(t + float(scene.depth_offset[i]), tw.depth_time_shift, tw.depth_row_readout, 0.0, H)
    return row_windows(t, tw.rgb_time_shift, 0.0, 0.0, H)


def render_twin_frame(scene, renderer, i: int) -> dict:
    """Frame ``i`` of a twin scene, as ``d2slam.synth.generate.render_frame`` returns a frame (see the module
    docstring for what the sensor does)."""
    cfg, tw = scene.cfg, scene.cfg.twin
    H, W = int(scene.intrinsics.height), int(scene.intrinsics.width)
    t = float(scene.t_rel[i])
    rngs = [np.random.default_rng([scene.seed, scene.sidx, i, k]) for k in (11, 12, 13)]
    ms, cpu = {}, {}
    wall0, cpu0 = time.perf_counter(), time.process_time()

    def lap(name):
        nonlocal wall0, cpu0
        w, c = time.perf_counter(), time.process_time()
        ms[name], cpu[name] = 1e3 * (w - wall0), 1e3 * (c - cpu0)
        wall0, cpu0 = w, c

    renderer.update(t)
    lap("bodies")
    lens = scene.lens
    # depth: each row at its own instant (the depth image's timestamp, shifted, and its rolling shutter), from the
    # sub-frame whose slice of time holds it
    zd, idd, z, nd = depth_rows(scene, renderer, *depth_windows(scene, i))
    # RGB: the average of sub-frames over each row's exposure
    start, end, windows = row_windows(t, tw.rgb_time_shift, tw.row_readout, tw.exposure, H)
    times, weights = subframe_plan(scene, start, end, windows, z, tw.subframe_px)
    weights = weights.astype(np.float32)
    acc = np.zeros((H, W, 3), np.float32)
    for k, Tk in enumerate(scene.camera.poses(times)):
        acc += weights[:, k, None, None] * lens(renderer.gl.render_colour(Tk)).astype(np.float32)
    lap("gl")
    rgb = np.clip(np.rint(acc), 0, 255).astype(np.uint8)
    rgb = rgb_sensor(rgb, (0.0, 0.0), rngs[1], cfg, bank_seed=scene.seed)
    depth = depth_to_png(zd, rngs[0], cfg, camera=scene.intrinsics)
    depth[shadow_holes(zd, cfg)] = 0
    clear_border(depth, tw.depth_border)
    lap("sensor")
    sim = simulate_segmenter(idd, zd, scene.person_ids, scene.K, rngs[2], cfg)
    lap("segmenter")
    return {"rgb": rgb, "depth": depth, "depth_clean": zd, "mask_gt": idd, "mask_sim": sim,
            "pose": scene.camera.poses([t])[0], "subframes": len(times), "depth_subframes": nd, "ms": ms,
            "cpu_ms": cpu}


def clear_border(depth: np.ndarray, border) -> None:
    """No depth on the image's border (top, bottom, left, right px: ``TwinConfig.depth_border``), in place."""
    top, bottom, left, right = border
    H, W = depth.shape
    depth[:top] = 0
    depth[H - bottom:] = 0
    depth[:, :left] = 0
    depth[:, W - right:] = 0


def twin_groundtruth(scene) -> tuple[np.ndarray, np.ndarray]:
    """(timestamps, (N, 7) tx ty tz qx qy qz qw): the recording's ground truth samples over the frames plus
    ``gt_margin``, placed in the room (``d2slam.synth.rigid.pose_rows``)."""
    path = scene.camera
    a = scene.t0 + scene.t_rel[0] - scene.cfg.gt_margin
    b = scene.t0 + scene.t_rel[-1] + scene.cfg.gt_margin
    sel = (path.gt_times >= a) & (path.gt_times <= b)
    return path.gt_times[sel], pose_rows(path.gt_poses[sel])
