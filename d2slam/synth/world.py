"""The synthetic world as OpenGL meshes: the room and moved objects (textured quads) and the people (skinned
bodies), drawn by ``d2slam.synth.gl.GLRenderer``.

Quads (``d2slam.synth.render.QuadSet``: parallelograms ``O + a U + b V``) become two triangles each with texture
coordinates into one texture atlas (every texture of the scene packed in rows, each padded by replicating its
border so that mipmapped sampling does not bleed between neighbours); each quad's Lambert shade is its vertex
colour. People are their posed body meshes, their garments' textures in the atlas too, with baked shading.
"""

from __future__ import annotations

import cv2
import numpy as np

from d2slam.synth.gl import GLRenderer
from d2slam.synth.render import QuadSet

ATLAS_WIDTH = 4096
ATLAS_PAD = 8


def build_atlas(textures: list[np.ndarray], width: int = ATLAS_WIDTH, pad: int = ATLAS_PAD):
    """Pack textures in rows (shelf packing, in list order) into one RGB image. Returns the atlas and (N, 4)
    texture rectangles ``u0, v0, u1, v1`` in normalised atlas coordinates (v down from the top row)."""
    x = y = row_h = 0
    places = []
    for t in textures:
        h, w = t.shape[:2]
        w2, h2 = min(w, width - 2 * pad), h
        if x + w2 + 2 * pad > width:
            x, y, row_h = 0, y + row_h, 0
        places.append((x, y, w2, h2))
        x += w2 + 2 * pad
        row_h = max(row_h, h2 + 2 * pad)
    H = max(y + row_h, 1)
    atlas = np.zeros((H, width, 3), np.uint8)
    rects = np.zeros((len(textures), 4))
    for i, (t, (x0, y0, w, h)) in enumerate(zip(textures, places)):
        tt = t if t.shape[1] == w else cv2.resize(t, (w, h), interpolation=cv2.INTER_AREA)
        atlas[y0:y0 + h + 2 * pad, x0:x0 + w + 2 * pad] = cv2.copyMakeBorder(tt, pad, pad, pad, pad,
                                                                                cv2.BORDER_REPLICATE)
        rects[i] = ((x0 + pad) / width, (y0 + pad) / H, (x0 + pad + w) / width, (y0 + pad + h) / H)
    return atlas, rects


def atlas_uv(uv: np.ndarray, tex: np.ndarray, rects: np.ndarray) -> np.ndarray:
    """Atlas texture coordinates of points at ``uv`` in [0, 1]^2 (u along a texture's columns, v down its rows) of
    textures ``tex`` (pyrender uploads the atlas's first row at v = 1)."""
    r = rects[tex]
    u = r[:, 0] + uv[:, 0] * (r[:, 2] - r[:, 0])
    v = r[:, 1] + uv[:, 1] * (r[:, 3] - r[:, 1])
    return np.stack([u, 1.0 - v], axis=1)


def quad_mesh(q: QuadSet, rects: np.ndarray):
    """Positions (4N, 3), triangles (2N, 3), colours (4N, 3) (the quads' shades) and texture coordinates (4N, 2)
    of N quads; texture columns run along U, rows along V (pyrender uploads the atlas's first row at v = 1); the
    triangles wind counter-clockwise seen from the visible side ``V x U``."""
    n = len(q)
    P = np.stack([q.O, q.O + q.U, q.O + q.U + q.V, q.O + q.V], axis=1).reshape(-1, 3)
    base = 4 * np.arange(n)[:, None]
    tri = np.concatenate([base + [0, 2, 1], base + [0, 3, 2]], axis=1).reshape(-1, 3)  # front face: V x U
    corners = np.tile(np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]]), (n, 1))
    uv = atlas_uv(corners, np.repeat(q.tex, 4), rects)
    col = np.repeat(q.shade, 4)[:, None].repeat(3, axis=1)
    return P, tri, col, uv


class WorldRenderer:
    """Renders a ``Scene`` at time t from pose T: the room uploaded once, people and moved objects per frame."""

    def __init__(self, scene):
        c = scene.cfg
        self.scene = scene
        atlas, self.rects = build_atlas(scene.textures)
        # a composite's people are drawn over a real image: their colour with its coverage (alpha)
        self.gl = GLRenderer(scene.canvas_K, *scene.canvas_size, atlas, c.near_plane, c.far_plane, c.gl_threads,
                             alpha=bool(getattr(scene, "composite", False)))
        if len(scene.static_set):  # a composite's scene has no room: the real recording is its background
            self.gl.set_static(*quad_mesh(scene.static_set, self.rects))

    def meshes(self, t: float) -> list[tuple]:
        """The people posed and the objects moved to time t (s): ``(object id, positions, triangles, colours,
        atlas uv)`` each, as :meth:`upload` takes them."""
        meshes = []
        for oid, item in self.scene.dynamic_meshes(t):
            if isinstance(item, QuadSet):
                meshes.append((oid, *quad_mesh(item, self.rects)))
            else:  # a person: vertices, triangles, shading, (uv, texture index) per vertex
                V, tri, shading, (uv, tex) = item
                meshes.append((oid, V, tri, shading, atlas_uv(uv, tex, self.rects)))
        return meshes

    def upload(self, meshes: list[tuple]) -> None:
        """Draw these dynamic meshes (:meth:`meshes`) from now on."""
        self.gl.set_dynamic(meshes)

    def update(self, t: float) -> None:
        """Pose the people and move the objects to time t (s): this frame's dynamic meshes, uploaded."""
        self.upload(self.meshes(t))

    def draw(self, T_world_camera: np.ndarray):
        """``rgb`` uint8, ``depth`` float32 m (0 = nothing), ``ids`` uint8 object ids of the world as last updated."""
        return self.gl.render(T_world_camera)

    def render(self, t: float, T_world_camera: np.ndarray):
        """``rgb`` uint8, ``depth`` float32 m (0 = nothing), ``ids`` uint8 object ids at time t (s)."""
        self.update(t)
        return self.draw(T_world_camera)

    def close(self) -> None:
        self.gl.close()
