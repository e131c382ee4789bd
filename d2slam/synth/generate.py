"""Write a synthetic sequence in the TUM RGB-D layout, plus ``mask_gt/``, ``mask_sim/`` and ``scene.json``.

Layout (CONTRIBUTING.md "Synthetic sequence format")::

    rgb/<t>.png        8-bit RGB PNG, t = RGB timestamp with 6 decimals (TUM style, e.g. 1341846313.592026)
    depth/<td>.png     16-bit PNG, metres * 5000, 0 = no measurement; td = t + a few ms
    rgb.txt depth.txt  '# ' comment header, then "timestamp filename" lines
    groundtruth.txt    100 Hz "timestamp tx ty tz qx qy qz qw", T_world_camera of the optical centre
                       (camera frame x right, y down, z forward), covering the frames with a margin
    mask_gt/<t>.png    uint8 object ids (0 = static scene), same stem as the RGB file
    mask_sim/<t>.png   uint8 simulated segmenter instances 1..n
    scene.json         intrinsics, seed, objects (kind, moved, moving_intervals), generator parameters

RGB and depth of a frame are both rendered at the RGB instant; the depth timestamp is only offset by a few ms (as
in TUM, where the two streams are not synchronised) so that readers exercise association.

Determinism: the scene (room, people, camera path, clock) is a function of (scenario, seed, frames); each frame's
noise comes from generators seeded with (seed, scenario, frame index, stream). Frames are rendered in a process
pool; the files do not depend on the number of workers or on scheduling.
"""

from __future__ import annotations

import dataclasses
import json
import multiprocessing as mp
import os
import shutil
import signal
import struct
import time
from pathlib import Path

import cv2
import numpy as np
from zlib_ng import zlib_ng

from d2slam import __version__
from d2slam.errors import D2SlamError
from d2slam.progress import PROGRESS, progress as _progress
from d2slam.synth.composite import composite_groundtruth
from d2slam.synth.compositing import render_composite_frame
from d2slam.synth.config import SynthConfig
from d2slam.synth.rigid import pose_rows
from d2slam.synth.scene import COMPOSITE_SCENARIOS, Scene
from d2slam.synth.segsim import simulate_segmenter
from d2slam.synth.sensor import depth_to_png, rgb_sensor
from d2slam.synth.twin import render_twin_frame, twin_groundtruth
from d2slam.synth.world import WorldRenderer

FORMAT = "d2slam-synth/2"
SUBDIRS = ("rgb", "depth", "mask_gt", "mask_sim")

_STATE: dict = {}


def stamp(t: float) -> str:
    """TUM file stem / timestamp text: 6 decimals."""
    return f"{t:.6f}"


def blur_vector(scene: Scene, t: float, T: np.ndarray, z_centre: float) -> tuple[float, float]:
    """Image motion (px) of the scene point seen at the image centre over the exposure around t."""
    e = scene.cfg.exposure
    if e <= 0 or not np.isfinite(z_centre) or z_centre <= 0:
        return 0.0, 0.0
    K = scene.K
    Xc = np.array([0.0, 0.0, z_centre])  # on the principal ray
    Xw = T[:3, :3] @ Xc + T[:3, 3]
    Ts = scene.camera.poses([t - e / 2, t + e / 2])
    uv = []
    for Tk in Ts:
        p = Tk[:3, :3].T @ (Xw - Tk[:3, 3])
        uv.append(K[:2, :2] @ (p[:2] / p[2]))
    d = uv[1] - uv[0]
    return float(d[0]), float(d[1])


def render_frame(scene: Scene, renderer: WorldRenderer, i: int) -> dict:
    """Everything of frame i as arrays: rgb (uint8 RGB), depth (uint16 PNG values), depth_clean (float32 m),
    mask_gt, mask_sim (uint8), plus the wall time (``ms``) and the CPU time of this process (``cpu_ms``: its OpenGL
    rasteriser threads included) of each stage: posing the bodies (``bodies``), the two OpenGL passes (``gl``), the
    sensor model, the simulated segmenter."""
    if scene.composite:
        return render_composite_frame(scene, renderer, i)
    if scene.recording is not None:
        return render_twin_frame(scene, renderer, i)
    cfg = scene.cfg
    t = float(scene.t_rel[i])
    rngs = [np.random.default_rng([scene.seed, scene.sidx, i, k]) for k in (11, 12, 13)]
    clock = _Stages()
    T = scene.camera.poses([t])[0]
    renderer.update(t)
    clock.lap("bodies")
    rgb, z, ids = renderer.draw(T)
    clock.lap("gl")
    cam = scene.intrinsics
    depth = depth_to_png(z, rngs[0], cfg, camera=cam)
    zc = float(z[int(cam.height) // 2, int(cam.width) // 2])
    rgb_out = rgb_sensor(rgb, blur_vector(scene, t, T, zc), rngs[1], cfg, bank_seed=scene.seed)
    clock.lap("sensor")
    sim = simulate_segmenter(ids, z, scene.person_ids, scene.K, rngs[2], cfg)
    clock.lap("segmenter")
    return {"rgb": rgb_out, "depth": depth, "depth_clean": z, "mask_gt": ids, "mask_sim": sim, "pose": T,
            "ms": clock.ms, "cpu_ms": clock.cpu_ms}


class _Stages:
    """Wall and process CPU time (ms) of consecutive stages."""

    def __init__(self):
        self.ms, self.cpu_ms = {}, {}
        self._wall, self._cpu = time.perf_counter(), time.process_time()

    def lap(self, name: str) -> None:
        wall, cpu = time.perf_counter(), time.process_time()
        self.ms[name] = 1e3 * (wall - self._wall)
        self.cpu_ms[name] = 1e3 * (cpu - self._cpu)
        self._wall, self._cpu = wall, cpu


PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def png_bytes(img: np.ndarray, compression: int) -> bytes:
    """A PNG file of ``img``: uint8 RGB (H, W, 3), uint8 or uint16 grey (H, W). Every row is SUB-filtered (each
    byte minus the one a pixel to its left) and compressed by zlib-ng with the Huffman-only strategy: on the noisy RGB
    and depth images about twice as fast as OpenCV's zlib with the same strategy, at the same size (measured:
    docs/deviations.md, `SynthConfig.png_compression`); any PNG reader decodes it."""
    h, w = img.shape[:2]
    rows = img.astype(">u2") if img.dtype == np.uint16 else np.ascontiguousarray(img, np.uint8)  # PNG: big-endian
    rows = rows.view(np.uint8).reshape(h, -1)
    bpp = rows.shape[1] // w  # bytes per pixel
    data = np.empty((h, rows.shape[1] + 1), np.uint8)
    data[:, 0] = 1  # filter type SUB
    data[:, 1:bpp + 1] = rows[:, :bpp]
    np.subtract(rows[:, bpp:], rows[:, :-bpp], out=data[:, bpp + 1:])
    z = zlib_ng.compressobj(int(compression), zlib_ng.DEFLATED, 15, 9, zlib_ng.Z_HUFFMAN_ONLY)
    idat = z.compress(data) + z.flush()
    head = struct.pack(">IIBBBBB", w, h, 8 * img.itemsize, 0 if img.ndim == 2 else 2, 0, 0, 0)

    def chunk(kind: bytes, body: bytes) -> bytes:
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib_ng.crc32(kind + body))

    return PNG_SIGNATURE + chunk(b"IHDR", head) + chunk(b"IDAT", idat) + chunk(b"IEND", b"")


def write_image(path: Path, img: np.ndarray, compression: int, labels: bool = False) -> None:
    """Write ``img`` (RGB order) as a PNG: the noisy images (RGB, depth) by :func:`png_bytes`, label images (masks)
    by OpenCV with zlib's default strategy and no filter (long runs of equal values: smaller, and faster to write
    and read than filtered)."""
    if not labels:
        path.write_bytes(png_bytes(img, compression))
        return
    params = [cv2.IMWRITE_PNG_COMPRESSION, int(compression), cv2.IMWRITE_PNG_STRATEGY,
              cv2.IMWRITE_PNG_STRATEGY_DEFAULT, cv2.IMWRITE_PNG_FILTER, cv2.IMWRITE_PNG_FILTER_NONE]
    if not cv2.imwrite(str(path), img, params):
        raise D2SlamError("could not write image", path=path)


def _frame_job(i: int) -> dict:
    scene, renderer, out = _STATE["scene"], _STATE["renderer"], _STATE["out"]
    cpu0 = time.process_time()
    f = render_frame(scene, renderer, i)
    clock = _Stages()
    comp = scene.cfg.png_compression
    name = stamp(scene.t0 + scene.t_rel[i]) + ".png"
    dname = stamp(scene.t0 + scene.t_rel[i] + scene.depth_offset[i]) + ".png"
    write_image(out / "rgb" / name, f["rgb"], comp)
    write_image(out / "depth" / dname, f["depth"], comp)
    write_image(out / "mask_gt" / name, f["mask_gt"], comp, labels=True)
    write_image(out / "mask_sim" / name, f["mask_sim"], comp, labels=True)
    if "mask_depth" in f:  # a composite: what its depth image shows (taken at another instant than its colour)
        write_image(out / "mask_depth" / dname, f["mask_depth"], comp, labels=True)
    clock.lap("write")
    cpu_ms = 1e3 * (time.process_time() - cpu0)
    counts = np.bincount(f["mask_gt"].ravel(), minlength=256)
    n = f["mask_gt"].size
    return {"index": i, "ms": {**f["ms"], **clock.ms}, "stage_cpu_ms": {**f["cpu_ms"], **clock.cpu_ms},
            "cpu_ms": cpu_ms,
            "person_fraction": float(sum(counts[p] for p in scene.person_ids)) / n,
            "moved_fraction": float(sum(counts[o] for o in scene.moved_object_ids)) / n,
            "sim_fraction": float(np.count_nonzero(f["mask_sim"])) / n,
            "hole_fraction": float(np.count_nonzero(f["depth"] == 0)) / n}


def _init_worker(args) -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the parent's: it stops the pool, workers say nothing
    cv2.setNumThreads(1)
    if "scene" not in _STATE:  # a spawned worker rebuilds the (deterministic) scene instead of inheriting it
        scenario, seed, frames, static_twin, cfg, out, recording = args
        scene = Scene(scenario, seed, frames, static_twin, cfg, recording)
        _STATE.update(scene=scene, renderer=WorldRenderer(scene), out=Path(out))


def groundtruth(scene: Scene) -> tuple[np.ndarray, np.ndarray]:
    """(timestamps, (N, 7) tx ty tz qx qy qz qw) at ``gt_rate`` Hz on an absolute grid covering the frames (a twin:
    its recording's samples, ``twin_groundtruth``)."""
    if scene.composite:
        return composite_groundtruth(scene)
    if scene.recording is not None:
        return twin_groundtruth(scene)
    c = scene.cfg
    a = scene.t0 + scene.t_rel[0] - c.gt_margin
    b = scene.t0 + scene.t_rel[-1] + c.gt_margin
    k = np.arange(np.ceil(a * c.gt_rate), np.floor(b * c.gt_rate) + 1)
    ts = k / c.gt_rate
    return ts, pose_rows(scene.camera.poses(ts - scene.t0))


def camera_json(cam) -> dict:
    """``scene.json``'s ``camera``: the intrinsics, the image size and the depth factor."""
    return {"fx": float(cam.fx), "fy": float(cam.fy), "cx": float(cam.cx), "cy": float(cam.cy),
            "width": int(cam.width), "height": int(cam.height), "depth_factor": float(cam.depth_factor)}


def scene_json(scene: Scene) -> dict:
    c = scene.cfg
    if scene.composite:
        return composite_scene_json(scene)
    if scene.recording is not None:
        return twin_scene_json(scene)
    return {
        "format": FORMAT,
        "scenario": scene.scenario,
        "seed": scene.seed,
        "frames": scene.frames,
        "static_twin": scene.static_twin,
        "camera": camera_json(scene.intrinsics),
        "objects": scene.objects_info(),
        "person_ids": scene.person_ids,
        "moved_object_ids": scene.moved_object_ids,
        "generator": {
            "name": "d2slam.synth", "version": __version__,
            "depth_rendered_at": "rgb_timestamp",
            "notes": "RGB and depth are rendered at the RGB timestamp; the depth timestamp is later by "
                     "depth_time_offset only. Poses: T_world_camera of the optical centre, camera x right / y down / "
                     "z forward, world Z up. moving_intervals are in the clock of rgb.txt. mask_sim comes from the "
                     "simulated segmenter (d2slam.synth.segsim), which never labels objects.",
            "start_time": scene.t0,
            "duration": scene.duration,
            "config": dataclasses.asdict(c),
            "depth_noise": dataclasses.asdict(scene.intrinsics.depth_noise),
        },
    }


def twin_scene_json(scene: Scene) -> dict:
    """``scene.json`` of a twin: the common keys (CONTRIBUTING.md), its camera with the lens distortion and the
    recording it follows (name, frames, the placement in the room)."""
    c, rec = scene.cfg, scene.recording
    cam = rec.camera
    camera = {**camera_json(cam), "bf": float(cam.bf), "name": f"{cam.name}-twin"}
    if c.twin.distortion and cam.has_distortion:
        camera["dist"] = [float(v) for v in cam.dist]
    return {
        "format": FORMAT, "scenario": scene.scenario, "seed": scene.seed, "frames": scene.frames,
        "static_twin": True, "camera": camera, "objects": [], "person_ids": [], "moved_object_ids": [],
        "recording": {"name": rec.name, "frames": len(rec), "placement": scene.camera.A.round(9).tolist()},
        "generator": {
            "name": "d2slam.synth", "version": __version__,
            "depth_rendered_at": "depth_timestamp" if c.twin.depth_at_depth_time else "rgb_timestamp",
            "notes": "The synthetic twin of a real recording: the office, static, along the recording's ground truth "
                     "(placed in the room by recording.placement, a 4x4 applied to its poses), at its RGB and depth "
                     "timestamps, through its camera with the lens distortion, the sensor of generator.config.twin. "
                     "Poses: T_world_camera of the optical centre, camera x right / y down / z forward, world Z up.",
            "start_time": scene.t0, "duration": scene.duration, "config": dataclasses.asdict(c),
            "depth_noise": dataclasses.asdict(cam.depth_noise),
        },
    }


def composite_scene_json(scene: Scene) -> dict:
    """``scene.json`` of a composite: the twin's keys (its camera with the lens distortion), its people and objects,
    the recording it is composited into (name, frames) and that recording's room as measured
    (``d2slam.synth.composite.RealRoom.summary``: the floor, the room frame the people were planned in, the free
    space's areas)."""
    out = twin_scene_json(scene)
    c, rec = scene.cfg, scene.recording
    out.update(static_twin=False, objects=scene.objects_info(), person_ids=scene.person_ids,
               moved_object_ids=scene.moved_object_ids)
    out["camera"]["name"] = f"{rec.camera.name}-composite"
    out["recording"] = {"name": rec.name, "frames": len(rec),
                        "room": scene.room.summary(c.composite.vis_min_coverage)}
    out["generator"]["notes"] = (
        "People composited into a real recording (d2slam.synth.compositing): rgb/ and depth/ are the recording's "
        "images with the people rendered along its ground truth (in the room frame recording.room.room_frame, a 4x4 "
        "applied to the recording's poses), at its RGB and depth timestamps, through its camera with the lens "
        "distortion and the sensor of generator.config.twin, z-tested against its depth. groundtruth.txt is the "
        "recording's, in its own world. mask_gt/: the ids in the colour image; mask_depth/ (named as depth/): the ids "
        "the depth image shows. moving_intervals are in the clock of rgb.txt.")
    return out


def _prepare_out(out: Path, subdirs=SUBDIRS) -> None:
    if out.exists() and not out.is_dir():
        raise D2SlamError("output path exists and is not a folder", path=out)
    if out.exists() and any(out.iterdir()) and not (out / "scene.json").exists():
        raise D2SlamError("output folder is not empty and holds no synthetic sequence (scene.json); refusing to "
                          "overwrite it", path=out)
    out.mkdir(parents=True, exist_ok=True)
    for d in subdirs:  # a re-run replaces the previous sequence entirely
        if (out / d).exists():
            shutil.rmtree(out / d)
        (out / d).mkdir()


def worker_count(frames: int, workers: int | None = None, cfg: SynthConfig | None = None) -> int:
    """The processes :func:`generate` renders ``frames`` frames with: ``workers``, or by default up to two, one per
    20 frames at most: starting a spawned worker is not free (measured: docs/deviations.md, `SynthConfig.workers`)."""
    if workers is None:
        return max(1, min((cfg or SynthConfig()).workers or min(2, os.cpu_count() or 1), frames // 20))
    return max(1, min(int(workers), frames))


def estimated_seconds(frames: int, workers: int | None = None, cfg: SynthConfig | None = None,
                      twin: bool = False, scenario: str | None = None) -> float:
    """What generating ``frames`` frames should take (``ProgressConfig.synth_setup_s``, ``synth_frame_s``; a twin's:
    ``synth_twin_frame_s``; a composite's: ``synth_composite_frame_s``), announced before it starts."""
    per_frame = PROGRESS.synth_composite_frame_s if scenario in COMPOSITE_SCENARIOS else \
        PROGRESS.synth_twin_frame_s if twin else PROGRESS.synth_frame_s
    return PROGRESS.synth_setup_s + frames * per_frame / worker_count(frames, workers, cfg)


def generate(scenario: str, out: str | Path, frames: int = 300, seed: int = 0, static_twin: bool = False,
             workers: int | None = None, cfg: SynthConfig | None = None, progress: bool = True,
             recording=None) -> dict:
    """Generate one sequence into ``out``; returns a summary (paths, per-frame fractions and stage timings). A twin
    scenario takes its ``recording`` (``d2slam.synth.twin.read_recording``), at most ``frames`` of its frames."""
    cfg = cfg or SynthConfig()
    out = Path(out)
    t_start = time.perf_counter()
    scene = Scene(scenario, seed, frames, static_twin, cfg, recording)
    frames, static_twin = scene.frames, scene.static_twin
    t_scene = time.perf_counter() - t_start
    _prepare_out(out, SUBDIRS + (("mask_depth",) if scene.composite else ()))
    n_gt = _write_lists(scene, out, scenario, seed, recording)
    n_workers = worker_count(frames, workers, cfg)
    t_frames = time.perf_counter()
    stats = _render_frames(scene, out, n_workers, progress, (scenario, seed, frames, static_twin, cfg, str(out),
                                                            recording))
    wall = time.perf_counter() - t_start
    frames_wall = time.perf_counter() - t_frames
    return {"out": out, "scenario": scenario, "seed": seed, "frames": frames, "static_twin": static_twin,
            "workers": n_workers, "person_ids": scene.person_ids, "moved_object_ids": scene.moved_object_ids,
            "objects": scene.objects_info(), "stats": stats, "seconds": wall, "seconds_frames": frames_wall,
            "seconds_scene": t_scene, "gt_poses": n_gt}


def _write_lists(scene: Scene, out: Path, scenario: str, seed: int, recording) -> int:
    """``rgb.txt``, ``depth.txt``, ``groundtruth.txt`` (TUM's comment lines first) and ``scene.json`` of ``scene``
    into ``out``; returns the ground truth's sample count."""
    stamps = [stamp(scene.t0 + t) for t in scene.t_rel]
    dstamps = [stamp(scene.t0 + t + d) for t, d in zip(scene.t_rel, scene.depth_offset)]
    if len(set(stamps)) != len(stamps):
        raise D2SlamError("duplicate frame timestamps (frame_jitter too large for fps)")
    on = f" on {recording.name}" if recording is not None else ""
    head = f"# file: 'd2slam-synth {scenario}{on} seed {seed}{' static twin' if scene.static_twin else ''}'\n"
    (out / "rgb.txt").write_text("# color images\n" + head + "# timestamp filename\n"
                                 + "".join(f"{s} rgb/{s}.png\n" for s in stamps))
    (out / "depth.txt").write_text("# depth maps\n" + head + "# timestamp filename\n"
                                   + "".join(f"{s} depth/{s}.png\n" for s in dstamps))
    ts, poses = groundtruth(scene)
    lines = "".join(f"{t:.4f} " + " ".join(f"{v:.6f}" for v in p[:3]) + " " + " ".join(f"{v:.7f}" for v in p[3:])
                    + "\n" for t, p in zip(ts, poses))
    (out / "groundtruth.txt").write_text("# ground truth trajectory\n" + head
                                         + "# timestamp tx ty tz qx qy qz qw\n" + lines)
    (out / "scene.json").write_text(json.dumps(scene_json(scene), indent=1) + "\n")
    return len(ts)


def _render_frames(scene: Scene, out: Path, n_workers: int, progress: bool, scene_args: tuple) -> list:
    """Render and write every frame of ``scene`` into ``out`` (``_frame_job``), here or on ``n_workers`` processes
    that rebuild the scene from ``scene_args``; the per-frame stats."""
    frames = scene.frames
    renderer = WorldRenderer(scene) if n_workers == 1 else None  # workers make their own OpenGL contexts
    _STATE.clear()
    _STATE.update(scene=scene, renderer=renderer, out=out)
    bar = dict(total=frames, desc=f"synth {scene.scenario}{' (static twin)' if scene.static_twin else ''}",
               unit="frame", enabled=progress)
    try:
        if n_workers == 1:
            prev = cv2.getNumThreads()
            cv2.setNumThreads(1)
            try:
                return [_frame_job(i) for i in _progress(range(frames), **bar)]
            finally:
                cv2.setNumThreads(prev)
        # spawn, not fork: a forked child inherits OpenCV's (possibly locked) thread pool and can hang; each worker
        # rebuilds the scene from its arguments, which is deterministic
        ctx = mp.get_context("spawn")
        with ctx.Pool(n_workers, initializer=_init_worker, initargs=(scene_args,)) as pool:
            return list(_progress(pool.imap(_frame_job, range(frames), chunksize=2), **bar))
    finally:
        _STATE.clear()
        if renderer is not None:
            renderer.close()
