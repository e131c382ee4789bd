"""A tiny z-buffered rasteriser of textured planar quads with OpenCV.

Every surface of the synthetic world (walls, furniture faces, body-part faces) is a planar parallelogram
``O + a U + b V`` (a, b in [0, 1]) carrying a texture. For each quad:

1. corners to the camera frame, back-face culling, Sutherland-Hodgman clipping against the near plane;
2. the texture is warped into the quad's bounding rectangle by the plane's homography
   ``H = K [U_c / w_tex, V_c / h_tex, O_c]`` (``cv2.warpPerspective``);
3. coverage by ``cv2.fillConvexPoly`` of the clipped polygon (sub-pixel, 4 fractional bits);
4. inverse depth is *affine* in (u, v) on a plane: ``1/z = (n_c^T K^-1 [u, v, 1]) / (n_c^T O_c)``, so the
   z-buffer test over the rectangle is two broadcasts and a compare.

The loop is over quads (a few hundred per frame), never over pixels. Pixel centres are at integer coordinates
(the TUM / OpenCV convention for ``K``).
"""

from __future__ import annotations

from dataclasses import dataclass
from types import SimpleNamespace

import cv2
import numpy as np

LIGHT = np.array([0.35, -0.55, 0.76]) / np.linalg.norm([0.35, -0.55, 0.76])


@dataclass
class Quad:
    """Parallelogram ``O, O+U, O+U+V, O+V`` (world metres) showing texture ``tex`` (index) with object id ``oid``.
    Texture column axis runs along ``U``, row axis along ``V``; the visible side is ``normal = V x U``."""

    O: np.ndarray
    U: np.ndarray
    V: np.ndarray
    tex: int
    oid: int = 0

    @property
    def normal(self) -> np.ndarray:
        n = np.cross(self.V, self.U)
        return n / np.linalg.norm(n)

    @property
    def shade(self) -> float:
        return float(0.6 + 0.4 * max(0.0, float(self.normal @ LIGHT)))


# Unit-cube faces: (outward axis, sign) -> corner offsets in {-1, 1}^3 of O, U and V (U along texture columns).
_FACES = []
for axis in range(3):
    for sign in (-1.0, 1.0):
        a1, a2 = (axis + 1) % 3, (axis + 2) % 3
        n = np.zeros(3)
        n[axis] = sign
        e1, e2 = np.zeros(3), np.zeros(3)
        e1[a1], e2[a2] = 2.0, 2.0
        # choose U, V so that V x U points along n (visible side outward)
        if np.cross(e2, e1) @ n < 0:
            e1, e2 = e2, e1
        origin = n - e1 / 2 - e2 / 2
        _FACES.append((origin, e1, e2))
_FACE_O = np.array([f[0] for f in _FACES])  # (6, 3) in half-size units
_FACE_U = np.array([f[1] for f in _FACES])
_FACE_V = np.array([f[2] for f in _FACES])


class QuadSet:
    """Many quads as arrays (vectorised projection and culling): ``O, U, V`` (N, 3), ``tex``, ``oid`` (N,)."""

    def __init__(self, O, U, V, tex, oid):
        self.O, self.U, self.V = (np.asarray(a, float).reshape(-1, 3) for a in (O, U, V))
        self.tex = np.asarray(tex, np.int64).reshape(-1)
        self.oid = np.asarray(oid, np.int64).reshape(-1)
        n = np.cross(self.V, self.U)
        n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
        self.shade = (0.6 + 0.4 * np.maximum(0.0, n @ LIGHT)).astype(np.float64)

    def __len__(self) -> int:
        return len(self.tex)

    @classmethod
    def from_quads(cls, quads: list[Quad]) -> "QuadSet":
        if not quads:
            return cls(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 3)), [], [])
        return cls([q.O for q in quads], [q.U for q in quads], [q.V for q in quads], [q.tex for q in quads],
                   [q.oid for q in quads])

    @classmethod
    def concat(cls, sets: list["QuadSet"]) -> "QuadSet":
        sets = [q for q in sets if len(q)]
        if not sets:
            return cls.from_quads([])
        out = cls.__new__(cls)
        for name in ("O", "U", "V", "tex", "oid", "shade"):
            setattr(out, name, np.concatenate([getattr(q, name) for q in sets]))
        return out


def boxes(T: np.ndarray, half: np.ndarray, tex, oid) -> QuadSet:
    """Outward faces of M boxes ``T[m] @ [-h, h]^3`` (T: (M, 4, 4) centre poses, half: (M, 3) half sizes).
    ``tex``: (M,) or (M, 6) texture indices (face order -x, +x, -y, +y, -z, +z); ``oid``: (M,) object ids."""
    T = np.asarray(T, float).reshape(-1, 4, 4)
    half = np.asarray(half, float).reshape(-1, 1, 3)
    R, t = T[:, :3, :3], T[:, :3, 3]
    O = np.einsum("mij,mfj->mfi", R, _FACE_O[None] * half) + t[:, None]
    U = np.einsum("mij,mfj->mfi", R, _FACE_U[None] * half)
    V = np.einsum("mij,mfj->mfi", R, _FACE_V[None] * half)
    M = len(T)
    tex = np.asarray(tex, np.int64)
    tex = np.broadcast_to(tex.reshape(M, -1), (M, 6))
    oid = np.broadcast_to(np.asarray(oid, np.int64).reshape(M, 1), (M, 6))
    return QuadSet(O.reshape(-1, 3), U.reshape(-1, 3), V.reshape(-1, 3), tex.reshape(-1), oid.reshape(-1))


def box_quads(T: np.ndarray, half: np.ndarray, tex: int | list[int], oid: int = 0) -> list[Quad]:
    """Six outward faces of the box ``T @ [-h, h]^3`` as ``Quad`` objects (set-up code; per frame use ``boxes``)."""
    qs = boxes(T[None], np.asarray(half, float)[None], np.asarray(tex).reshape(1, -1), [oid])
    return [Quad(qs.O[i], qs.U[i], qs.V[i], int(qs.tex[i]), int(qs.oid[i])) for i in range(6)]


def _clip_near(P: np.ndarray, near: float) -> np.ndarray:
    """Sutherland-Hodgman clip of a convex polygon (n, 3) against the half space z >= near."""
    inside = P[:, 2] >= near
    if inside.all():
        return P
    out = []
    n = len(P)
    for i in range(n):
        a, b = P[i], P[(i + 1) % n]
        ia, ib = inside[i], inside[(i + 1) % n]
        if ia:
            out.append(a)
        if ia != ib:
            s = (near - a[2]) / (b[2] - a[2])
            out.append(a + s * (b - a))
    return np.array(out) if len(out) >= 3 else np.empty((0, 3))


class Renderer:
    """Z-buffered quad rasteriser for a pinhole camera ``K`` of ``width x height`` pixels."""

    def __init__(self, K: np.ndarray, width: int, height: int, textures: list[np.ndarray], near: float = 0.05):
        self.K = np.asarray(K, float)
        self.Kinv = np.linalg.inv(self.K)
        self.width, self.height = int(width), int(height)
        self.textures = textures
        self.near = float(near)
        self._u = np.arange(self.width, dtype=np.float32)
        self._v = np.arange(self.height, dtype=np.float32)

    def render(self, quads: QuadSet, T_world_camera: np.ndarray):
        """Returns ``rgb`` (H, W, 3) uint8, ``invz`` (H, W) float32 inverse depth (0 = nothing), ``ids`` uint8.

        Projection, back-face culling and bounding boxes are vectorised over all quads; the loop then visits the
        visible quads front to back (nearest corner first), so hidden quads fail the z-test before any warp."""
        H, W = self.height, self.width
        rgb = np.zeros((H, W, 3), np.uint8)
        invz = np.zeros((H, W), np.float32)
        ids = np.zeros((H, W), np.uint8)
        if isinstance(quads, list):
            quads = QuadSet.from_quads(quads)
        if len(quads) == 0:
            return rgb, invz, ids
        view = self._project(quads, T_world_camera)
        for i in view.order:
            self._draw(quads, view, int(i), rgb, invz, ids)
        return rgb, invz, ids

    def _project(self, quads: QuadSet, T_world_camera: np.ndarray) -> SimpleNamespace:
        """Every quad in the camera frame (origin ``Oc``, edges ``Uc``, ``Vc``, normal ``nc``, plane offset ``dd``,
        corners ``P`` with depths ``z``, pixels ``u``, ``v``; ``full``: all corners ahead of the near plane) and the
        visible ones front to back (``order``)."""
        H, W = self.height, self.width
        R, C = T_world_camera[:3, :3], T_world_camera[:3, 3]
        K, near = self.K, self.near
        fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
        Oc = (quads.O - C) @ R  # == (R^T (O - C))^T
        Uc, Vc = quads.U @ R, quads.V @ R
        nc = np.cross(Vc, Uc)
        dd = np.einsum("ij,ij->i", nc, Oc)
        P = np.stack([Oc, Oc + Uc, Oc + Uc + Vc, Oc + Vc], axis=1)  # (N, 4, 3)
        z = P[:, :, 2]
        ahead = z >= near
        cand = (dd < 0) & ahead.any(axis=1)
        zs = np.where(ahead, z, near)
        u = fx * P[:, :, 0] / zs + cx
        v = fy * P[:, :, 1] / zs + cy
        full = ahead.all(axis=1)
        # quads that need clipping get a conservative box here and an exact one after clipping
        inside = (~full) | ((u.max(1) >= 0) & (u.min(1) < W) & (v.max(1) >= 0) & (v.min(1) < H))
        order = np.flatnonzero(cand & inside)
        order = order[np.argsort(z[order].min(axis=1), kind="stable")]
        return SimpleNamespace(Oc=Oc, Uc=Uc, Vc=Vc, nc=nc, dd=dd, P=P, z=z, u=u, v=v, full=full, order=order)

    def _draw(self, quads: QuadSet, view: SimpleNamespace, i: int, rgb, invz, ids) -> None:
        """Quad ``i`` (of ``view``) drawn where it is nearer than what is drawn already: its texture warped into its
        box, its inverse depth and id."""
        H, W = self.height, self.width
        K, near = self.K, self.near
        fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
        if view.full[i]:
            uu, vv, zi = view.u[i], view.v[i], view.z[i]
        else:
            Pi = _clip_near(view.P[i], near)
            if len(Pi) == 0:
                return
            uu = fx * Pi[:, 0] / Pi[:, 2] + cx
            vv = fy * Pi[:, 1] / Pi[:, 2] + cy
            zi = Pi[:, 2]
        x0, x1 = max(int(np.floor(uu.min())), 0), min(int(np.ceil(uu.max())) + 1, W)
        y0, y1 = max(int(np.floor(vv.min())), 0), min(int(np.ceil(vv.max())) + 1, H)
        if x1 <= x0 or y1 <= y0:
            return
        w, h = x1 - x0, y1 - y0
        cov = np.zeros((h, w), np.uint8)
        pts = np.round(np.stack([uu - x0, vv - y0], axis=1) * 16.0).astype(np.int32)
        cv2.fillConvexPoly(cov, pts, 1, cv2.LINE_8, 4)
        # inverse depth, affine in (u, v) on the plane
        a = (view.nc[i] @ self.Kinv) / view.dd[i]
        iz = (np.float32(a[0]) * self._u[x0:x1])[None, :] \
            + (np.float32(a[1]) * self._v[y0:y1] + np.float32(a[2]))[:, None]
        # on the polygon 1/z lies between its vertices' values; rasterised edge pixels just outside a near edge-on
        # quad would extrapolate far beyond, so clamp
        np.clip(iz, np.float32(1.0 / zi.max()), np.float32(1.0 / zi.min()), out=iz)
        zb = invz[y0:y1, x0:x1]
        m = (iz > zb) & (cov != 0)
        if not m.any():
            return
        tex = self.textures[quads.tex[i]]
        th, tw = tex.shape[:2]
        Hm = K @ np.column_stack([view.Uc[i] / tw, view.Vc[i] / th, view.Oc[i]])
        Hm[0] -= x0 * Hm[2]
        Hm[1] -= y0 * Hm[2]
        patch = cv2.warpPerspective(tex, Hm, (w, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
        shade = quads.shade[i]
        if shade < 0.999:
            patch = cv2.convertScaleAbs(patch, alpha=shade)
        # cv2.copyTo writes through the numpy views (row-strided Mats); checked by tests/test_synth_render
        mu = m.view(np.uint8)
        cv2.copyTo(patch, mu, rgb[y0:y1, x0:x1])
        cv2.copyTo(iz, mu, zb)
        ids[y0:y1, x0:x1][m] = quads.oid[i]
