"""OpenGL rendering of the synthetic world with pyrender (offscreen, Mesa EGL / llvmpipe by default).

One ``GLRenderer`` per process holds a pyrender scene: the static room (one textured mesh drawing from a texture
atlas) and, per frame, the dynamic meshes (people with baked vertex colours, moved objects textured from the atlas).
``render(T_world_camera)`` makes two passes:

1. colour: flat shading (colours are baked: vertex colours times texture), 4x multisampling (anti-aliased edges),
   back faces culled (every surface is seen from its front: closed bodies and boxes, the room from inside), as in
   the id pass, so that no sample on a silhouette shows the far side of a body and half of the small body triangles
   are never rasterised;
2. segmentation: into a single-sample framebuffer (pixel centres; no multisample buffer to resolve), every mesh
   drawn in the colour (object id, 0, 0), the room in black; its depth buffer gives the metric depth (linearised
   here) and its red channel the per-pixel object id, so that the truth mask and the depth agree pixel for pixel.

``PYOPENGL_PLATFORM`` must be set before OpenGL is imported: ``import_pyrender`` sets it to ``egl`` unless the user
chose another platform (``osmesa`` needs Debian's ``libosmesa6``).
"""

from __future__ import annotations

import os

import numpy as np

from d2slam.errors import D2SlamError

PLATFORM_ENV = "PYOPENGL_PLATFORM"
INSTALL = "pip install pyrender==0.1.45 PyOpenGL==3.1.10 (pyrender pins PyOpenGL 3.1.0; install 3.1.10 after it)"
CONTEXT_HELP = ("the EGL platform needs Mesa's EGL and software rasteriser: `apt-get install libegl1 libegl-mesa0 "
                "libgl1-mesa-dri`; or use OSMesa: `apt-get install libosmesa6` and set PYOPENGL_PLATFORM=osmesa")

# pyrender's OpenGL camera looks along -z with y up; the TUM / OpenCV optical frame looks along +z with y down
_GL_FROM_CV = np.diag([1.0, -1.0, -1.0, 1.0])


def import_pyrender():
    """Import pyrender with a headless OpenGL platform (``egl`` unless ``PYOPENGL_PLATFORM`` says otherwise)."""
    os.environ.setdefault(PLATFORM_ENV, "egl")
    try:
        import pyrender
    except ImportError as e:
        raise D2SlamError(f"the renderer package is missing or broken ({e}): {INSTALL}") from None
    except Exception as e:  # noqa: BLE001 - PyOpenGL raises various errors when its platform library is absent
        raise D2SlamError(f"cannot load OpenGL for {PLATFORM_ENV}={os.environ[PLATFORM_ENV]} "
                          f"({type(e).__name__}: {e}); {CONTEXT_HELP}") from None
    return pyrender


_READER: dict = {}


def _reader_class(pr):
    """pyrender's ``Renderer`` with a fixed drawing order and a leaner id pass: the colour pass resolves and reads its
    colour only; the id pass draws into the single-sample framebuffer and reads its red channel and its depth,
    linearised in float32 without boolean indexing (pyrender reads and linearises the depth after every pass)."""
    if "cls" in _READER:
        return _READER["cls"]
    from OpenGL import GL

    class Reader(pr.Renderer):
        def _sorted_mesh_nodes(self, scene):
            # draw in a fixed order (the room, then object ids): surfaces at exactly equal depth (a sole on the
            # floor) resolve the same way whatever the context's history (pyrender iterates a set of nodes)
            return sorted(scene.mesh_nodes, key=lambda n: n.name)

        def _configure_forward_pass_viewport(self, flags):
            super()._configure_forward_pass_viewport(flags)
            if flags & pr.RenderFlags.SEG:  # pixel centres only: the single-sample framebuffer, nothing to resolve
                GL.glBindFramebuffer(GL.GL_DRAW_FRAMEBUFFER, self._main_fb)

        def _read_main_framebuffer(self, scene, flags):
            w, h = self._main_fb_dims
            GL.glPixelStorei(GL.GL_PACK_ALIGNMENT, 1)
            if not flags & pr.RenderFlags.SEG:
                GL.glBindFramebuffer(GL.GL_READ_FRAMEBUFFER, self._main_fb_ms)
                GL.glBindFramebuffer(GL.GL_DRAW_FRAMEBUFFER, self._main_fb)
                GL.glBlitFramebuffer(0, 0, w, h, 0, 0, w, h, GL.GL_COLOR_BUFFER_BIT, GL.GL_LINEAR)
                GL.glBindFramebuffer(GL.GL_READ_FRAMEBUFFER, self._main_fb)
                fmt, ch = (GL.GL_RGBA, 4) if getattr(self, "d2slam_alpha", False) else (GL.GL_RGB, 3)
                colour = np.frombuffer(GL.glReadPixels(0, 0, w, h, fmt, GL.GL_UNSIGNED_BYTE), np.uint8)
                return colour.reshape(h, w, ch)[::-1], None
            GL.glBindFramebuffer(GL.GL_READ_FRAMEBUFFER, self._main_fb)
            ids = np.frombuffer(GL.glReadPixels(0, 0, w, h, GL.GL_RED, GL.GL_UNSIGNED_BYTE), np.uint8)
            d = np.frombuffer(GL.glReadPixels(0, 0, w, h, GL.GL_DEPTH_COMPONENT, GL.GL_FLOAT), np.float32)
            d = d.reshape(h, w)[::-1]
            cam = scene.main_camera_node.camera
            n, f = np.float32(cam.znear), np.float32(cam.zfar)
            ndc = np.float32(2.0) * d - np.float32(1.0)
            z = (np.float32(2.0) * n * f) / (f + n - ndc * (f - n))
            return ids.reshape(h, w)[::-1], np.where(d < np.float32(1.0), z, np.float32(0.0))

    _READER["cls"] = Reader
    return Reader


class GLRenderer:
    """Offscreen renderer of a pinhole camera ``K`` (``width`` x ``height``) with a texture ``atlas`` (uint8 RGB).
    ``alpha``: the colour pass gives RGBA over a transparent background, the alpha the share of a pixel's samples
    that a surface covers (the layer of people composited into a real image, ``d2slam.synth.compositing``)."""

    def __init__(self, K: np.ndarray, width: int, height: int, atlas: np.ndarray, near: float = 0.05,
                 far: float = 20.0, threads: int = 1, alpha: bool = False):
        # llvmpipe's rasteriser threads (read when the context is created; renders do not depend on it)
        os.environ.setdefault("LP_NUM_THREADS", str(int(threads)))
        pr = import_pyrender()
        self.pr = pr
        self.width, self.height = int(width), int(height)
        try:
            self.renderer = pr.OffscreenRenderer(self.width, self.height)
        except Exception as e:  # noqa: BLE001 - context creation fails with platform-specific exception types
            raise D2SlamError(f"cannot create an offscreen OpenGL context with {PLATFORM_ENV}="
                              f"{os.environ.get(PLATFORM_ENV)} ({type(e).__name__}: {e}); {CONTEXT_HELP}") from None
        self.renderer._renderer.__class__ = _reader_class(pr)
        self.renderer._renderer.d2slam_alpha = bool(alpha)
        self.scene = pr.Scene(bg_color=[0.0, 0.0, 0.0, 0.0 if alpha else 1.0], ambient_light=[1.0, 1.0, 1.0])
        cam = pr.IntrinsicsCamera(float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2]), znear=near,
                                  zfar=far)
        self.cam_node = self.scene.add(cam, pose=np.eye(4))
        sampler = pr.Sampler(magFilter=pr.constants.GLTF.LINEAR, minFilter=pr.constants.GLTF.LINEAR_MIPMAP_LINEAR,
                             wrapS=pr.constants.GLTF.CLAMP_TO_EDGE, wrapT=pr.constants.GLTF.CLAMP_TO_EDGE)
        tex = pr.Texture(source=np.ascontiguousarray(atlas), source_channels="RGB", sampler=sampler)
        self.material = pr.MetallicRoughnessMaterial(baseColorFactor=[1.0, 1.0, 1.0, 1.0], baseColorTexture=tex,
                                                     doubleSided=False)
        self.plain = pr.MetallicRoughnessMaterial(baseColorFactor=[1.0, 1.0, 1.0, 1.0], doubleSided=False)
        self.static_nodes: list = []
        self.dynamic: list = []

    def _mesh(self, positions, triangles, colours, uv=None):
        pr = self.pr
        col = np.concatenate([np.asarray(colours, np.float32), np.ones((len(colours), 1), np.float32)], axis=1)
        prim = pr.Primitive(positions=np.asarray(positions, np.float32), indices=np.asarray(triangles, np.uint32),
                            color_0=col, texcoord_0=None if uv is None else np.asarray(uv, np.float32),
                            material=self.material if uv is not None else self.plain, mode=pr.constants.GLTF.TRIANGLES)
        return pr.Mesh([prim])

    def set_static(self, positions, triangles, colours, uv) -> None:
        """The room: one textured mesh (world coordinates), drawn black in the id pass."""
        for n in self.static_nodes:
            self.scene.remove_node(n)
        self.static_nodes = [self.scene.add(self._mesh(positions, triangles, colours, uv), name="0000")]

    def set_dynamic(self, meshes: list[tuple[int, np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]]) -> None:
        """This frame's dynamic meshes: (object id, positions (world), triangles, colours, uv or None)."""
        for _, n in self.dynamic:
            self.scene.remove_node(n)
        self.dynamic = [(oid, self.scene.add(self._mesh(P, tri, col, uv), name=f"{k + 1:04d}"))
                        for k, (oid, P, tri, col, uv) in enumerate(meshes)]

    def render(self, T_world_camera: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``rgb`` (H, W, 3) uint8, ``depth`` (H, W) float32 metres (0 = nothing), ``ids`` (H, W) uint8."""
        rgb = self.render_colour(T_world_camera)
        depth, ids = self.render_depth(T_world_camera)
        return rgb, depth, ids

    def render_colour(self, T_world_camera: np.ndarray) -> np.ndarray:
        """The colour pass alone: ``rgb`` (H, W, 3) uint8 (with ``alpha``: RGBA (H, W, 4))."""
        self.scene.set_pose(self.cam_node, np.asarray(T_world_camera, float) @ _GL_FROM_CV)
        rgb, _ = self.renderer.render(self.scene, flags=self.pr.RenderFlags.FLAT)
        return np.ascontiguousarray(rgb)

    def render_depth(self, T_world_camera: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The id pass alone: ``depth`` (H, W) float32 metres (0 = nothing), ``ids`` (H, W) uint8."""
        self.scene.set_pose(self.cam_node, np.asarray(T_world_camera, float) @ _GL_FROM_CV)
        seg_map = {n: (0, 0, 0) for n in self.static_nodes}
        seg_map.update({n: (int(oid), 0, 0) for oid, n in self.dynamic})
        ids, depth = self.renderer.render(self.scene, flags=self.pr.RenderFlags.SEG, seg_node_map=seg_map)
        return np.ascontiguousarray(depth, dtype=np.float32), np.ascontiguousarray(ids)

    def close(self) -> None:
        self.renderer.delete()
