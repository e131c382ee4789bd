"""The engine's camera geometry: pinhole projection with the RGB-D virtual stereo coordinate, ORB-SLAM's
``isInFrustum`` test with scale prediction, and poses (``Tcw`` world-to-camera, 4x4)."""

from __future__ import annotations

import numpy as np

from d2slam.data.base import Camera
from d2slam.slam.config import SlamConfig
from d2slam.slam.frame import close_depth, undistort

EPS_Z = 1e-9  # depths below this count as behind the camera (no division by ~0)


def inv(T: np.ndarray) -> np.ndarray:
    """Inverse of a rigid 4x4 transform."""
    R, t = T[:3, :3], T[:3, 3]
    out = np.eye(4)
    out[:3, :3] = R.T
    out[:3, 3] = -R.T @ t
    return out


def image_bounds(camera: Camera) -> tuple[float, float, float, float]:
    """(min x, max x, min y, max y) of the undistorted image: ORB-SLAM3 ``Frame::ComputeImageBounds`` (the image
    corners undistorted; without distortion the image itself, 0..width by 0..height)."""
    if not camera.has_distortion:
        return 0.0, float(camera.width), 0.0, float(camera.height)
    w, h = float(camera.width), float(camera.height)
    c = undistort(np.array([[0.0, 0.0], [w, 0.0], [0.0, h], [w, h]]), camera)
    return min(c[0, 0], c[2, 0]), max(c[1, 0], c[3, 0]), min(c[0, 1], c[1, 1]), max(c[2, 1], c[3, 1])


class Projector:
    """What every stage needs of the camera: intrinsics, ``bf`` and its baseline, the close-point depth, the
    pyramid scales."""

    def __init__(self, camera: Camera, config: SlamConfig):
        self.camera = camera
        self.cfg = config.engine
        self.K = camera.K
        self.bf = float(camera.bf)
        self.b = self.bf / camera.fx
        self.width, self.height = camera.width, camera.height
        self.bounds = image_bounds(camera)
        self.th_depth_m = close_depth(camera, config.engine)
        self.n_levels = config.orb.n_levels
        self.scales = config.orb.scale_factor ** np.arange(config.orb.n_levels)
        self.log_scale = np.log(config.orb.scale_factor)

    def project(self, Tcw: np.ndarray, X: np.ndarray):
        """Pixel coordinates (u, v) and depth z of world points ``X`` (M, 3) seen from ``Tcw``."""
        return self.pixels(X @ Tcw[:3, :3].T + Tcw[:3, 3])

    def pixels(self, Xc: np.ndarray):
        """Pixel coordinates (u, v) and depth z of camera points ``Xc`` (M, 3)."""
        z = Xc[:, 2]
        zs = np.where(z > EPS_Z, z, EPS_Z)
        u = self.K[0, 0] * Xc[:, 0] / zs + self.K[0, 2]
        v = self.K[1, 1] * Xc[:, 1] / zs + self.K[1, 2]
        return u, v, z

    def in_image(self, u, v):
        """Whether undistorted pixel coordinates fall within the undistorted image (``image_bounds``)."""
        x0, x1, y0, y1 = self.bounds
        return (u >= x0) & (u <= x1) & (v >= y0) & (v <= y1)

    def backproject(self, kps: np.ndarray, z: np.ndarray) -> np.ndarray:
        """(M, 3) camera coordinates of pixels ``kps`` (M, 2) at depths ``z``."""
        K = self.K
        return np.c_[(kps[:, 0] - K[0, 2]) * z / K[0, 0], (kps[:, 1] - K[1, 2]) * z / K[1, 1], z]

    def in_frustum(self, points, Tcw: np.ndarray, pids: np.ndarray):
        """ORB-SLAM ``isInFrustum`` for map points ``pids`` (of ``points``, the map's point columns) seen from
        ``Tcw``: in front, in the image, within the scale-invariance distance range, viewing angle within
        ``TrackingConfig.frustum_view_cos``. Returns the visible (pids, u, v, z, predicted level, viewing cosine)."""
        cfg = self.cfg
        X = points.pos[pids]
        u, v, z = self.project(Tcw, X)
        PO = X - inv(Tcw)[:3, 3]
        dist = np.linalg.norm(PO, axis=1)
        view_cos = np.einsum("ij,ij->i", PO, points.normal[pids]) / np.maximum(dist, 1e-12)
        ok = (z > 0) & self.in_image(u, v) & (dist >= cfg.tracking.frustum_dmin_factor * points.dmin[pids]) & \
            (dist <= cfg.tracking.frustum_dmax_factor * points.dmax[pids]) & (view_cos >= cfg.tracking.frustum_view_cos)
        pids, u, v, z, dist, view_cos = pids[ok], u[ok], v[ok], z[ok], dist[ok], view_cos[ok]
        level = np.clip(np.ceil(np.log(points.dmax[pids] / dist) / self.log_scale), 0, self.n_levels - 1).astype(
            np.int64)
        return pids, u, v, z, level, view_cos
