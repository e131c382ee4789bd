"""Small rigid-body helpers of the synthetic world: rotations about the axes, 4x4 transforms, look-at frames.

World frame: metres, Z up, the floor at Z = 0. Camera frame: the TUM / OpenCV optical frame (x right, y down,
z forward). A *heading* is an angle in the floor plane from +x; ``yaw_pose(xy, h)`` is the frame whose +y axis
points along heading ``h`` (a person's or a chair's forward).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation


def rot_x(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]], float)


def rot_y(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]], float)


def rot_z(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]], float)


def rots(axis: int, a: np.ndarray) -> np.ndarray:
    """(N, 3, 3) rotations about a coordinate axis by angles a (N,)."""
    a = np.asarray(a, float)
    c, s = np.cos(a), np.sin(a)
    R = np.zeros(a.shape + (3, 3))
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    R[..., axis, axis] = 1.0
    R[..., i, i], R[..., j, j] = c, c
    R[..., i, j], R[..., j, i] = -s, s
    return R


def tf(R=None, t=None) -> np.ndarray:
    T = np.eye(4)
    if R is not None:
        T[:3, :3] = R
    if t is not None:
        T[:3, 3] = t
    return T


def yaw_pose(xy, heading: float, z: float = 0.0) -> np.ndarray:
    """4x4 pose on the floor at ``xy`` (height ``z``) whose +y axis points along ``heading``."""
    return tf(rot_z(heading - np.pi / 2), [xy[0], xy[1], z])


def look_at(C: np.ndarray, target: np.ndarray, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """(N, 3, 3) camera-to-world rotations whose optical axis (z) points from C (N, 3) to target (N, 3) or (3,),
    x to the right and y down (TUM / OpenCV optical frame)."""
    C = np.atleast_2d(C)
    f = np.broadcast_to(target, C.shape) - C
    f = f / np.linalg.norm(f, axis=1, keepdims=True)
    r = np.cross(f, np.asarray(up, float))
    r /= np.linalg.norm(r, axis=1, keepdims=True)
    d = np.cross(f, r)
    return np.stack([r, d, f], axis=2)


def pose_rows(T: np.ndarray) -> np.ndarray:
    """(N, 7) ``tx ty tz qx qy qz qw`` of poses (N, 4, 4) (a TUM ground truth's columns), the quaternion's sign kept
    continuous (no flips between samples) and its first qw >= 0."""
    q = Rotation.from_matrix(T[:, :3, :3]).as_quat()  # x y z w
    flip = np.concatenate([[1.0], np.sign(np.sum(q[1:] * q[:-1], axis=1))])
    flip[flip == 0] = 1.0
    q *= np.cumprod(flip)[:, None]
    if q[0, 3] < 0:
        q = -q
    return np.concatenate([T[:, :3, 3], q], axis=1)
