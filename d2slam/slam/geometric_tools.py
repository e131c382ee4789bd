"""Two-view geometry of local mapping (ORB-SLAM3 ``GeometricTools`` and the checks of
``LocalMapping::CreateNewMapPoints``): the fundamental matrix between two keyframes, linear triangulation, and the
tests a triangulated point passes before it enters the map (parallax or depth, in front of both cameras,
reprojection chi-square in both keyframes, scale consistency). Vectorised over the matches of a keyframe pair."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from d2slam.slam.projection import Projector, inv


def skew(t: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -t[2], t[1]], [t[2], 0.0, -t[0]], [-t[1], t[0], 0.0]])


def fundamental_matrix(T1w: np.ndarray, T2w: np.ndarray, K: np.ndarray) -> np.ndarray:
    """``F12`` with ``x1^T F12 x2 = 0`` for pixels x1 of keyframe 1 and x2 of keyframe 2 (poses world-to-camera;
    ORB-SLAM3 ``Pinhole::epipolarConstrain``: ``K^-T [t12]x R12 K^-1``, ``T12 = T1w T2w^-1``)."""
    T12 = T1w @ inv(T2w)
    Kinv = np.linalg.inv(K)
    return Kinv.T @ skew(T12[:3, 3]) @ T12[:3, :3] @ Kinv


def epipole(T1w: np.ndarray, T2w: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Keyframe 1's centre projected into keyframe 2 (pixels; meaningless behind the camera, as in ORB-SLAM3, which
    divides by the signed depth: hence not ``Projector.pixels``, which holds the depth above zero)."""
    C2 = T2w[:3, :3] @ inv(T1w)[:3, 3] + T2w[:3, 3]
    z = C2[2] if abs(C2[2]) > 1e-12 else 1e-12
    return np.array([K[0, 0] * C2[0] / z + K[0, 2], K[1, 1] * C2[1] / z + K[1, 2]])


def triangulate(xn1: np.ndarray, xn2: np.ndarray, T1w: np.ndarray, T2w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """ORB-SLAM3 ``GeometricTools::Triangulate`` for (M, 2) normalised coordinates seen from two poses: the DLT
    (the right singular vector of the 4x4 system with the least singular value). Returns ((M, 3) points, valid:
    a finite homogeneous coordinate)."""
    A = np.stack([xn1[:, :1] * T1w[2] - T1w[0], xn1[:, 1:2] * T1w[2] - T1w[1],
                  xn2[:, :1] * T2w[2] - T2w[0], xn2[:, 1:2] * T2w[2] - T2w[1]], axis=1)
    if len(A) == 0:
        return np.zeros((0, 3)), np.zeros(0, dtype=bool)
    Xh = np.linalg.svd(A)[2][:, 3, :]
    ok = Xh[:, 3] != 0
    return Xh[:, :3] / np.where(ok, Xh[:, 3], 1.0)[:, None], ok


@dataclass
class View:
    """One keyframe's side of the matches: pose, the matched keypoints' pixels, u_R (-1: none), depth, octave."""

    Tcw: np.ndarray
    uv: np.ndarray
    ur: np.ndarray
    depth: np.ndarray
    octave: np.ndarray

    @property
    def centre(self) -> np.ndarray:
        return inv(self.Tcw)[:3, 3]


def _rays(view: View, proj: Projector) -> tuple[np.ndarray, np.ndarray]:
    """The keypoints' normalised coordinates (camera coordinates at depth 1) and their rays in the world (R_wc xn)."""
    xn = proj.backproject(view.uv, np.ones(len(view.uv)))
    return xn, xn @ view.Tcw[:3, :3]


def _from_depth(view: View, proj: Projector) -> np.ndarray:
    Twc = inv(view.Tcw)
    return proj.backproject(view.uv, view.depth) @ Twc[:3, :3].T + Twc[:3, 3]


def _reprojects(view: View, X: np.ndarray, proj: Projector, sigma2: np.ndarray, chi2_mono: float,
                chi2_stereo: float) -> np.ndarray:
    """In front of the camera and within the chi-square test: ``(du^2 + dv^2) / sigma^2`` (mono) or with ``du_R``
    at 1 px x scale too (where the keypoint has u_R)."""
    u, v, z = proj.project(view.Tcw, X)
    e2 = (u - view.uv[:, 0]) ** 2 + (v - view.uv[:, 1]) ** 2
    stereo = view.ur >= 0
    e2s = e2 + (u - proj.bf / np.where(z > 0, z, 1.0) - view.ur) ** 2
    return (z > 0) & np.where(stereo, e2s <= chi2_stereo * sigma2, e2 <= chi2_mono * sigma2)


def new_points(v1: View, v2: View, proj: Projector, max_cos_parallax: float, chi2_mono: float, chi2_stereo: float,
               ratio_factor: float) -> tuple[np.ndarray, np.ndarray]:
    """ORB-SLAM3 ``CreateNewMapPoints``' per-match geometry for matched keypoints of keyframes 1 and 2: the point is
    triangulated when the rays' parallax exceeds the depth's (the stereo parallax ``2 atan(b / 2z)`` of keyframe 1
    where it has depth, else of keyframe 2's), is positive, and (without depth in either) ``cos`` is below
    ``max_cos_parallax``; otherwise it is back-projected from the depth of keyframe 1 (or 2) when that parallax is
    the larger; otherwise dropped. It must then lie in front of both keyframes, reproject within the chi-square
    tests in both, and its distances to the two centres must agree with the keypoints' octaves within
    ``ratio_factor``. Returns ((M, 3) points, kept)."""
    scales = proj.scales
    xn1, ray1 = _rays(v1, proj)
    xn2, ray2 = _rays(v2, proj)
    cos_rays = np.einsum("ij,ij->i", ray1, ray2) / (np.linalg.norm(ray1, axis=1) * np.linalg.norm(ray2, axis=1))
    s1, s2 = v1.ur >= 0, v2.ur >= 0
    b = proj.b
    cos_s1 = np.where(s1, np.cos(2 * np.arctan2(b / 2, np.where(s1, v1.depth, 1.0))), cos_rays + 1)
    cos_s2 = np.where(~s1 & s2, np.cos(2 * np.arctan2(b / 2, np.where(s2, v2.depth, 1.0))), cos_rays + 1)
    cos_stereo = np.minimum(cos_s1, cos_s2)
    tri = (cos_rays < cos_stereo) & (cos_rays > 0) & (s1 | s2 | (cos_rays < max_cos_parallax))
    use1 = ~tri & s1 & (cos_s1 < cos_s2)
    use2 = ~tri & ~use1 & s2 & (cos_s2 < cos_s1)
    X, ok = triangulate(xn1, xn2, v1.Tcw, v2.Tcw)
    X[use1], X[use2] = _from_depth(v1, proj)[use1], _from_depth(v2, proj)[use2]
    ok = (tri & ok) | use1 | use2
    sig1, sig2 = scales[v1.octave] ** 2, scales[v2.octave] ** 2
    ok &= _reprojects(v1, X, proj, sig1, chi2_mono, chi2_stereo)
    ok &= _reprojects(v2, X, proj, sig2, chi2_mono, chi2_stereo)
    d1 = np.linalg.norm(X - v1.centre, axis=1)
    d2 = np.linalg.norm(X - v2.centre, axis=1)
    ratio_dist = d2 / np.where(d1 > 0, d1, 1.0)
    ratio_octave = scales[v1.octave] / scales[v2.octave]
    ok &= (d1 > 0) & (d2 > 0) & (ratio_dist * ratio_factor >= ratio_octave) & (ratio_dist <= ratio_octave * ratio_factor)
    return X, ok
