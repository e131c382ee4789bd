"""The images of a composite: the benchmark's people rendered along a real recording's trajectory and put into its
real colour and depth images (``d2slam synth real_walking --on TUM_DIR``; the people and where they walk:
``d2slam.synth.composite``).

Everything the renders take from the recording is the twin's (``d2slam.synth.twin``, ``TwinConfig``: measured on the
recording): its camera and lens (rendered through a pinhole canvas, then distorted), its RGB and depth times, its
ground truth interpolated at every instant a row of an image is taken.

- **Depth** (:func:`composite_depth`): the people's depth is rendered row by row at the instants the real depth
  image's rows were taken (its timestamp, ``depth_time_shift``, its rolling shutter), the people posed at each
  sub-frame's instant. It goes through the benchmark's Kinect model (``d2slam.synth.sensor``: the depth noise and
  quantisation, holes at the depth edges the people make, hole blobs on them) and the projector's shadow the people
  cast on what lies behind them (``twin.shadow_holes``). Then the z-test: a pixel shows a person where the person's
  noisy depth is nearer than the real depth, its holes filled (:func:`filled_depth`: a hole takes the nearest depth on
  its outline, so that nobody shows through a black monitor the Kinect does not measure); elsewhere the real depth is
  kept as it was, untouched. The border the registered depth never covers stays a hole.
- **Colour** (:func:`composite_colour`): the people are rendered with their alpha (the share of a pixel's samples they
  cover, 4x multisampling) in sub-frames spread over each row's exposure (``exposure``, ``rgb_time_shift``,
  ``row_readout``: the motion blur and rolling shutter measured on the recording), each sub-frame z-tested against the
  real scene's depth at the colour instant: the real depth image, its holes filled, moved from the instants its rows
  were taken to the colour image's (:func:`real_depth_at_colour`: every valid real depth pixel back-projected through the lens with
  its row's pose and projected into the colour image with its row's pose, the nearest kept, one-pixel cracks
  filled). The real image is the background: ``out = real (1 - A) + g C`` with ``C`` the people's premultiplied
  colour and ``A`` their coverage averaged over the exposure, ``g`` the recording's exposure and white balance
  against the office's (:func:`colour_gain`: the recording's mean colour over the office's, per channel; the office's
  textures are what the people's were made to sit in); then the twin's RGB noise on the people's share of each
  pixel only (the real background has its own).
- **Truth**: ``mask_gt`` holds an object's id where it covers at least half of a pixel's exposure at the pixel's
  centre in the colour image (the sub-frames' id passes, z-tested); ``mask_depth`` (the depth image's stem) where the
  depth image shows it. ``mask_sim`` is the simulated segmenter on ``mask_gt`` (``d2slam.synth.segsim``).

A frame whose exposure and depth windows show nobody at their start, middle and end is the real frame unchanged.
Deterministic: each frame's noise from generators seeded with (seed, scenario, frame index, stream).
"""

from __future__ import annotations

import time
from functools import lru_cache

import cv2
import numpy as np

from d2slam.data.tum import TumSequence
from d2slam.synth.segsim import simulate_segmenter
from d2slam.synth.sensor import depth_holes, depth_to_png
from d2slam.synth.twin import (clear_border, depth_rows, depth_windows, distort_normalised, row_windows, shadow_holes,
                               subframe_plan, undistort_normalised)


class _Clock:
    """Wall and process CPU time (ms) of consecutive stages."""

    def __init__(self):
        self.ms, self.cpu_ms = {}, {}
        self._w, self._c = time.perf_counter(), time.process_time()

    def lap(self, name: str) -> None:
        w, c = time.perf_counter(), time.process_time()
        self.ms[name] = self.ms.get(name, 0.0) + 1e3 * (w - self._w)
        self.cpu_ms[name] = self.cpu_ms.get(name, 0.0) + 1e3 * (c - self._c)
        self._w, self._c = w, c


# --------------------------------------------------------------------------------------------------
# the recording's frames
# --------------------------------------------------------------------------------------------------
def real_sequence(scene):
    """The recording's folder as a ``TumSequence`` (opened once per process)."""
    seq = getattr(scene, "_real_seq", None)
    if seq is None:
        seq = TumSequence(scene.recording.root, camera=scene.recording.camera)
        scene._real_seq = seq
    return seq


def real_frame(scene, i: int) -> tuple[np.ndarray, np.ndarray]:
    """(RGB uint8, depth float32 m) of the recording's frame behind frame ``i``."""
    f = real_sequence(scene)[int(scene.recording.frame_index[i])]
    return f.rgb, f.depth


@lru_cache(maxsize=2)
def _rays(camera) -> np.ndarray:
    """(H, W, 2) the undistorted normalised coordinates of every pixel of ``camera``."""
    K = camera.K
    v, u = np.mgrid[0:camera.height, 0:camera.width].astype(np.float64)
    x = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1]], axis=-1)
    return undistort_normalised(x, camera.dist) if camera.has_distortion else x


def colour_gain(scene) -> np.ndarray:
    """(3,) the factor on the people's colour: the recording's mean colour (per channel, the median over every
    ``fuse_stride``-th frame of the frames' means) over the office's (``CompositeConfig.office_rgb_mean``)."""
    g = getattr(scene, "_gain", None)
    if g is None:
        seq, rec = real_sequence(scene), scene.recording
        idx = rec.frame_index[np.arange(0, len(rec), scene.cfg.composite.fuse_stride)]
        means = np.array([seq.rgb_frame(int(k)).rgb.reshape(-1, 3).mean(axis=0) for k in idx])
        g = np.median(means, axis=0) / np.asarray(scene.cfg.composite.office_rgb_mean, float)
        scene._gain = g
    return g


# --------------------------------------------------------------------------------------------------
# the real scene's depth at the colour image's instants
# --------------------------------------------------------------------------------------------------
def filled_depth(real_z: np.ndarray, border) -> np.ndarray:
    """(H, W) float32: the real depth with its holes filled for the z-test, so that nobody shows through what the
    Kinect did not measure: a hole inside the registered depth's border takes the nearest depth on its outline (a
    black monitor screen takes its frame's or the desk's in front of it; the projector's shadow beside an edge the
    nearer side's); the border the registered depth never covers (``TwinConfig.depth_border``), and the holes that
    reach it, take the nearest valid pixel's depth. All 0 when no pixel is valid."""
    z = np.asarray(real_z, np.float32)
    hole = z <= 0
    if not hole.any() or hole.all():
        return z.copy()
    H, W = z.shape
    top, bottom, left, right = border
    edge = np.ones((H, W), bool)
    edge[top:H - bottom, left:W - right] = False
    n, lab = cv2.connectedComponents(hole.view(np.uint8), connectivity=4)
    outer = np.unique(lab[edge & hole])
    low = np.full(n, np.inf, np.float32)  # each hole's nearest depth on its outline
    for dy, dx in ((0, 1), (0, -1), (1, 0), (-1, 0)):
        a = lab[max(dy, 0):H + min(dy, 0), max(dx, 0):W + min(dx, 0)]  # a hole pixel ...
        b = z[max(-dy, 0):H + min(-dy, 0), max(-dx, 0):W + min(-dx, 0)]  # ... and its valid neighbour
        sel = (a > 0) & (b > 0)
        np.minimum.at(low, a[sel], b[sel])
    low[outer] = np.inf
    out = z.copy()
    inner = hole & np.isfinite(low[lab])
    out[inner] = low[lab[inner]]
    rest = out <= 0
    if rest.any():  # the border's holes: the nearest valid pixel's depth
        # every pixel's label: that of the nearest valid pixel (each valid pixel its own)
        _, near = cv2.distanceTransformWithLabels(rest.view(np.uint8), cv2.DIST_L2, 5,
                                                 labelType=cv2.DIST_LABEL_PIXEL)
        valid = ~rest
        values = np.zeros(int(near.max()) + 1, np.float32)
        values[near[valid]] = out[valid]
        out[rest] = values[near[rest]]
    return out


def _project(Xw: np.ndarray, T: np.ndarray, camera) -> tuple[np.ndarray, np.ndarray]:
    """(pixels (N, 2) through the lens, depth (N,)) of world points Xw (N, 3) in the cameras T (N, 4, 4) or (4, 4)."""
    R, t = (T[..., :3, :3], T[..., :3, 3])
    d = Xw - t
    Xc = np.einsum("nji,nj->ni", R, d) if R.ndim == 3 else d @ R
    z = Xc[:, 2]
    x = Xc[:, :2] / np.where(z > 1e-6, z, 1e-6)[:, None]
    if camera.has_distortion:
        x = distort_normalised(np.clip(x, -2.0, 2.0), camera.dist)
    K = camera.K
    return np.stack([x[:, 0] * K[0, 0] + K[0, 2], x[:, 1] * K[1, 1] + K[1, 2]], axis=1), z


def depth_png(z: np.ndarray, factor: float) -> np.ndarray:
    """A depth image (float32 m, read from a 16-bit PNG of ``factor`` steps a metre) as its PNG values again."""
    return np.rint(np.asarray(z, np.float64) * float(factor)).astype(np.uint16)


def real_depth_at_colour(scene, real_z: np.ndarray, depth_rows_t: np.ndarray, colour_rows_t: np.ndarray) -> np.ndarray:
    """(H, W) float32: the real depth image ``real_z`` (its rows taken at ``depth_rows_t``, s from the first frame)
    seen from the colour image (its rows at ``colour_rows_t``): every valid pixel back-projected through the lens with
    its row's pose, projected with the pose of the colour row it lands in (found in two steps: the middle row's pose,
    then that row's), the nearest kept; a hole (0) where none lands, one-pixel cracks filled with the nearest of their
    3 x 3 neighbours."""
    cam = scene.recording.camera
    H, W = real_z.shape
    v, u = np.nonzero(real_z > 0)
    if not len(v):
        return np.zeros((H, W), np.float32)
    z = real_z[v, u].astype(np.float64)
    ray = _rays(cam)[v, u]
    Td = scene.camera.poses(depth_rows_t)[v]
    Xc = np.concatenate([ray * z[:, None], z[:, None]], axis=1)
    Xw = np.einsum("nij,nj->ni", Td[:, :3, :3], Xc) + Td[:, :3, 3]
    Tc = scene.camera.poses(colour_rows_t)
    uv, _ = _project(Xw, Tc[H // 2], cam)
    row = np.clip(np.rint(uv[:, 1]), 0, H - 1).astype(np.int64)
    uv, zc = _project(Xw, Tc[row], cam)
    ui, vi = np.rint(uv[:, 0]).astype(np.int64), np.rint(uv[:, 1]).astype(np.int64)
    ok = (zc > 0.05) & (ui >= 0) & (ui < W) & (vi >= 0) & (vi < H)
    flat, zc = vi[ok] * W + ui[ok], zc[ok].astype(np.float32)
    order = np.argsort(-zc, kind="stable")  # far first: the nearest written last wins
    out = np.full(H * W, np.inf, np.float32)
    out[flat[order]] = zc[order]
    out = out.reshape(H, W)
    near = cv2.erode(out, np.ones((3, 3), np.uint8), borderType=cv2.BORDER_REPLICATE)
    out = np.where(np.isfinite(out), out, near)
    return np.where(np.isfinite(out), out, 0.0).astype(np.float32)


# --------------------------------------------------------------------------------------------------
# one frame
# --------------------------------------------------------------------------------------------------
class _Poser:
    """Poses the people for an instant (the world renderer's dynamic meshes), once per instant."""

    def __init__(self, renderer):
        self.renderer, self.t = renderer, None

    def __call__(self, t: float) -> None:
        if self.t != t:
            self.renderer.update(float(t))
            self.t = t


def _anyone(scene, renderer, poser, times) -> bool:
    """Does any of the canvas depth renders at ``times`` show somebody?"""
    for t in times:
        poser(t)
        z, _ = renderer.gl.render_depth(scene.camera.poses([t])[0])
        if (z > 0).any():
            return True
    return False


def composite_depth(scene, renderer, poser, i: int, real_z: np.ndarray, rng) -> dict:
    """The depth image of frame ``i`` (module docstring): ``depth`` (uint16 PNG values), ``ids`` (the object shown
    at each pixel of it, 0 for the real scene), ``zp`` (the people's clean depth, m, rendered at the depth rows'
    instants), ``canvas`` (the canvas depth at the window's middle, for the sub-frame counts), ``subframes``."""
    cfg, cc, cam = scene.cfg, scene.cfg.composite, scene.intrinsics
    start, end, windows = depth_windows(scene, i)
    zp, idp, canvas, nd = depth_rows(scene, renderer, start, end, windows, at=poser)
    real_png = depth_png(real_z, cam.depth_factor)
    person = zp > 0
    if not person.any():
        return {"depth": real_png, "ids": np.zeros(zp.shape, np.uint8), "zp": zp, "canvas": canvas, "subframes": nd}
    behind = filled_depth(real_z, cfg.twin.depth_border)  # the real scene, its holes filled
    front = person & (zp < behind)
    noisy = depth_to_png(np.where(front, zp, 0.0).astype(np.float32), rng, cfg, holes=False, camera=cam)
    zn = noisy.astype(np.float32) / np.float32(cam.depth_factor)
    shown = front & (zn < behind)  # the z-test on the measured depth: the nearer surface wins
    combined = np.where(shown, zp, real_z).astype(np.float32)
    far, edge, blob = depth_holes(combined, rng, cfg)
    k = np.ones((2 * cc.edge_band_px + 1,) * 2, np.uint8)
    band = cv2.dilate(shown.view(np.uint8), k).view(bool) & cv2.dilate((~shown).view(np.uint8), k).view(bool)
    hole = (shown & (far | blob)) | (band & edge) | shadow_holes(combined, cfg, casters=shown)
    depth = real_png.copy()
    depth[shown] = noisy[shown]
    depth[hole] = 0
    clear_border(depth, cfg.twin.depth_border)
    ids = np.where(shown & (depth > 0), idp, 0).astype(np.uint8)
    return {"depth": depth, "ids": ids, "zp": zp, "canvas": canvas, "subframes": nd}


def composite_colour(scene, renderer, poser, i: int, real_rgb: np.ndarray, real_col_z: np.ndarray,
                     canvas: np.ndarray, ids_all: list[int]) -> dict:
    """The people's layer of frame ``i``'s colour image (module docstring): ``colour`` (H, W, 3) float32
    premultiplied, ``alpha`` (H, W) their coverage over the exposure, ``cover`` (len(ids_all), H, W) each object's share
    of the exposure at the pixels' centres, ``zmin`` the nearest person depth seen over the exposure (0: none),
    ``subframes``."""
    cfg, tw, lens = scene.cfg, scene.cfg.twin, scene.lens
    H, W = int(scene.intrinsics.height), int(scene.intrinsics.width)
    t = float(scene.t_rel[i])
    start, end, windows = row_windows(t, tw.rgb_time_shift, tw.row_readout, tw.exposure, H)
    times, weights = subframe_plan(scene, start, end, windows, canvas, cfg.composite.subframe_px,
                                   cfg.composite.subframes_min)
    weights = weights.astype(np.float32)
    colour = np.zeros((H, W, 3), np.float32)
    alpha = np.zeros((H, W), np.float32)
    cover = np.zeros((len(ids_all), H, W), np.float32)
    zmin = np.full((H, W), np.inf, np.float32)
    real_inf = np.where(real_col_z > 0, real_col_z, np.inf).astype(np.float32)
    k3 = np.ones((3, 3), np.uint8)
    for k, (tk, Tk) in enumerate(zip(times, scene.camera.poses(times))):
        poser(float(tk))
        rgba = lens(renderer.gl.render_colour(Tk))
        zk, ik = renderer.gl.render_depth(Tk)
        zk, ik = lens(zk, nearest=True), lens(ik, nearest=True)
        a = rgba[..., 3].astype(np.float32) * np.float32(1.0 / 255.0)
        if not a.any():
            continue
        # an anti-aliased edge pixel whose centre misses the body takes the nearest body depth beside it
        zb = np.where(zk > 0, zk, np.inf).astype(np.float32)
        zb = np.minimum(zb, cv2.erode(zb, k3, borderType=cv2.BORDER_REPLICATE))
        seen = (zb < real_inf).astype(np.float32)
        w = weights[:, k, None]
        colour += (w * seen)[..., None] * rgba[..., :3].astype(np.float32)
        alpha += w * seen * a
        for j, oid in enumerate(ids_all):
            cover[j] += w * seen * (ik == oid)
        zmin = np.minimum(zmin, np.where((zk > 0) & (seen > 0), zk, np.inf))
    return {"colour": colour, "alpha": np.clip(alpha, 0.0, 1.0), "cover": cover,
            "zmin": np.where(np.isfinite(zmin), zmin, 0.0).astype(np.float32), "subframes": len(times)}


def render_composite_frame(scene, renderer, i: int) -> dict:
    """Frame ``i`` of a composite, as ``d2slam.synth.generate.render_frame`` returns a frame (module docstring), plus
    ``mask_depth`` (the ids the depth image shows)."""
    cfg, tw = scene.cfg, scene.cfg.twin
    H, W = int(scene.intrinsics.height), int(scene.intrinsics.width)
    rngs = [np.random.default_rng([scene.seed, scene.sidx, i, k]) for k in (11, 12, 13)]
    clock = _Clock()
    real_rgb, real_z = real_frame(scene, i)
    clock.lap("read")
    poser = _Poser(renderer)
    t = float(scene.t_rel[i])
    cstart, cend, cwin = row_windows(t, tw.rgb_time_shift, tw.row_readout, tw.exposure, H)
    dstart, dend, dwin = depth_windows(scene, i)
    probe = (cstart, 0.5 * (cstart + cend), cend, dstart, 0.5 * (dstart + dend), dend)
    ids_all = list(scene.person_ids) + list(scene.moved_object_ids or [o.oid for o in scene.objects])
    quiet = not _anyone(scene, renderer, poser, probe)
    clock.lap("bodies")
    if quiet:
        zeros = np.zeros((H, W), np.uint8)
        depth = depth_png(real_z, scene.intrinsics.depth_factor)
        return {"rgb": real_rgb, "depth": depth, "depth_clean": real_z, "mask_gt": zeros, "mask_depth": zeros,
                "mask_sim": zeros, "pose": scene.camera.poses([t])[0], "subframes": 0, "depth_subframes": 0,
                "ms": clock.ms, "cpu_ms": clock.cpu_ms}
    d = composite_depth(scene, renderer, poser, i, real_z, rngs[0])
    clock.lap("depth")
    real_col = real_depth_at_colour(scene, filled_depth(real_z, tw.depth_border), dwin[:, 0], cwin.mean(axis=1))
    clock.lap("warp")
    c = composite_colour(scene, renderer, poser, i, real_rgb, real_col, d["canvas"], ids_all)
    clock.lap("colour")
    gain = colour_gain(scene).astype(np.float32)
    A = c["alpha"]
    out = real_rgb.astype(np.float32) * (1.0 - A)[..., None] + c["colour"] * gain
    if tw.rgb_noise_sigma > 0 and A.any():
        out += rngs[1].standard_normal(out.shape, dtype=np.float32) * np.float32(tw.rgb_noise_sigma) * A[..., None]
    rgb = np.clip(np.rint(out), 0, 255).astype(np.uint8)
    cover = c["cover"]
    mask = np.zeros((H, W), np.uint8)
    if len(ids_all):
        best = np.argmax(cover, axis=0)
        hit = np.take_along_axis(cover, best[None], axis=0)[0] >= 0.5
        mask[hit] = np.asarray(ids_all, np.uint8)[best[hit]]
    # the clean depth of the colour image: the people's where they are shown, the real scene's elsewhere
    clean = np.where(mask > 0, c["zmin"], real_col).astype(np.float32)
    clock.lap("compose")
    sim = simulate_segmenter(mask, clean, scene.person_ids, scene.K, rngs[2], cfg)
    clock.lap("segmenter")
    return {"rgb": rgb, "depth": d["depth"], "depth_clean": clean, "mask_gt": mask, "mask_depth": d["ids"],
            "mask_sim": sim, "pose": scene.camera.poses([t])[0], "subframes": c["subframes"],
            "depth_subframes": d["subframes"], "ms": clock.ms, "cpu_ms": clock.cpu_ms}
