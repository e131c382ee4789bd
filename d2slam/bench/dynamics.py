"""Speed of D2SLAM's dynamics modules per frame (target: all modules together <= 3 ms for 1000 keypoints, about 800
matches and two person masks at 640x480).

Inputs are seeded synthetic two-view scenes (``d2slam.dynamics.toy``: a moving camera, person-sized masks moving
sideways, Kinect-range depth with holes), or with ``--sequence DIR`` the hook inputs the engine makes on the first
``--sequence-frames`` frames of a real or synthetic sequence (run once with the ``d2slam`` filter and the masks a
``d2slam run`` would read; the toy scenes' matches are cleaner than real ones, so RANSAC stops sooner there). The
classifier is called once per frame, each call timed module by module
(``FrameDiagnostics.timings_ms``, wall clock) and as a whole (wall clock and process CPU time of the call:
the CPU time is the figure that stays meaningful when other processes load the machine). The robust keypoint depth
(``depth.keypoint_depth``) runs on the engine's side (``FilterInput.kp_depth``) and is timed on its own line.
``d2slam-flow`` (ours) tracks keypoints in the grey images, which the toy scenes do not have: it is timed with
``--sequence`` only, with the flow's share printed apart from the paper's modules. With ``--sequence`` the engine's
whole filter stage (the hook: the frame-to-frame matches, the filter's inputs and the ``d2slam`` classifier; target
<= 5 ms per frame) is also timed while the inputs are recorded, in thread CPU time and wall clock.
"""

from __future__ import annotations

import os
import time

import cv2
import numpy as np

from d2slam.config import DEFAULT
from d2slam.data import SyntheticSequence, open_sequence
from d2slam.dynamics.config import DynamicsConfig
from d2slam.dynamics.toy import two_view_scene
from d2slam.errors import D2SlamError
from d2slam.run.methods import DYNAMICS, get_filter, get_method, mask_kind
from d2slam.run.sequence import ensure_vocabulary
from d2slam.segmentation import masks_for, stack_masks
from d2slam.slam.depth import keypoint_depth
from d2slam.slam.engine import Engine

DESCRIPTION = "time the dynamics modules per frame (1000 keypoints, ~800 matches, two masks, 640x480)"
TARGET_STAGE_MS = 5.0  # the engine's whole filter stage on a walking sequence (--sequence)


def add_arguments(parser) -> None:
    parser.add_argument("--method", default="d2slam", help="classifier mode (default d2slam; 'all' = every mode)")
    parser.add_argument("--keypoints", type=int, default=1000)
    parser.add_argument("--matches", type=int, default=800)
    parser.add_argument("--masks", type=int, default=2)
    parser.add_argument("--scenes", type=int, default=20, help="distinct seeded scenes, cycled")
    parser.add_argument("--frames", type=int, default=300, help="timed frames (after --warmup)")
    parser.add_argument("--warmup", type=int, default=20)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--threads", type=int, default=1, help="OpenCV threads (cv2.setNumThreads)")
    parser.add_argument("--sequence", default=None, metavar="DIR",
                        help="time on the engine's hook inputs of a sequence (synthetic or TUM) instead of toy scenes")
    parser.add_argument("--sequence-frames", type=int, default=60, help="frames of --sequence to record (default 60)")
    parser.add_argument("--sequence-masks", dest="masks_kind", choices=("onnx", "sim", "gt", "truth"), default=None,
                        help="--sequence: the masks the engine reads (default: as `d2slam run` reads them)")


def _stats(values: list[float]) -> tuple[float, float, float]:
    a = np.asarray(values)
    return float(a.mean()), float(np.median(a)), float(np.percentile(a, 95))


def _run_mode(mode: str, scenes, args) -> dict[str, list[float]]:
    flt = get_filter(mode, DynamicsConfig())
    out: dict[str, list[float]] = {}
    for i in range(args.warmup + args.frames):
        inp = scenes[i % len(scenes)]
        c0, t0 = time.process_time(), time.perf_counter()
        flt(inp)
        wall, cpu = (time.perf_counter() - t0) * 1e3, (time.process_time() - c0) * 1e3
        if i < args.warmup:
            continue
        for k, v in flt.last.timings_ms.items():
            out.setdefault(k, []).append(v)
        out.setdefault("wall (call)", []).append(wall)
        out.setdefault("cpu time (call)", []).append(cpu)
    return out


class _Timed:
    """Wraps a callable: wall and thread CPU milliseconds of each call (``wall``, ``cpu``); attributes pass through."""

    def __init__(self, fn):
        self._fn, self.wall, self.cpu = fn, [], []

    def __call__(self, *args, **kwargs):
        c0, t0 = time.thread_time(), time.perf_counter()
        try:
            return self._fn(*args, **kwargs)
        finally:
            self.wall.append((time.perf_counter() - t0) * 1e3)
            self.cpu.append((time.thread_time() - c0) * 1e3)

    def __getattr__(self, name):
        return getattr(self._fn, name)


def recorded_inputs(path: str, frames: int, masks: str | None = None, stage: dict | None = None) -> list:
    """The ``FilterInput`` of frames 1 .. ``frames``-1 of a sequence as the engine gives them to the ``d2slam`` filter
    (default config, masks as ``d2slam run --masks MASKS`` reads them; by default the ONNX segmenter's, through the
    mask cache). ``stage`` (a dict) receives the engine's filter stage of those frames, milliseconds per frame:
    ``wall``, ``cpu`` (thread CPU time) of the whole hook (frame-to-frame matches, the inputs, the classifier) and
    ``filter_cpu`` of the classifier alone."""
    seq = open_sequence(path)
    kind = mask_kind(get_method("d2slam"), masks, synthetic=isinstance(seq, SyntheticSequence))
    shape = (seq.camera.height, seq.camera.width)
    ensure_vocabulary(DEFAULT)
    engine = Engine(seq.camera, DEFAULT, get_filter("d2slam", DEFAULT))
    engine.hook.filter = flt = _Timed(engine.hook.filter)
    engine.hook = hook = _Timed(engine.hook)
    out = []
    for i in range(min(frames, len(seq))):
        f = seq[i]
        engine.process(f.gray, f.depth, i, f.timestamp, masks=stack_masks(masks_for(seq, i, kind, DEFAULT), shape))
        if i > 0:
            out.append(engine.last_filter_input)
    if stage is not None:
        stage.update(wall=hook.wall[1:], cpu=hook.cpu[1:], filter_cpu=flt.cpu[1:])
    return out


def run(args) -> int:
    cv2.setNumThreads(args.threads)
    stage: dict = {}
    scenes = _scenes(args, stage)
    kd = []
    for i in range(args.frames):
        inp = scenes[i % len(scenes)]
        t0 = time.perf_counter()
        keypoint_depth(inp.depth, inp.kps, DEFAULT.orb.depth_patch_radius)
        kd.append((time.perf_counter() - t0) * 1e3)
    modes = list(DYNAMICS) if args.method == "all" else [args.method]
    if args.method not in DYNAMICS and args.method != "all":
        raise D2SlamError(f"unknown method {args.method!r}; choose one of all, {', '.join(DYNAMICS)}")
    for mode in modes:
        if getattr(get_filter(mode), "use_flow", False) and not args.sequence:
            # the toy scenes have no images: the flow would be skipped and the figure would be d2slam's
            print(f"\nmethod {mode}: needs grey images (LK flow), timed with --sequence only")
            if args.method == "all":
                continue
            return 2
        _print_mode(mode, _run_mode(mode, scenes, args))
    print(f"load average (1, 5, 15 min): {' '.join(f'{x:.2f}' for x in os.getloadavg())} on {os.cpu_count()} CPUs "
          "(wall-clock figures are only meaningful on an idle machine; CPU time is steadier)")
    mean, med, p95 = _stats(kd)
    print(f"\nengine side: keypoint_depth (3x3 median) {mean:.3f} / {med:.3f} / {p95:.3f} ms (mean/median/p95)")
    if stage:
        (wm, wmed, _), (cm, cmed, _), (fm, fmed, _) = (_stats(stage[k]) for k in ("wall", "cpu", "filter_cpu"))
        rest = np.asarray(stage["cpu"]) - np.asarray(stage["filter_cpu"])
        print(f"engine's filter stage (the hook: frame-to-frame matches, inputs, d2slam classifier) while recording "
              f"{len(stage['cpu'])} frames, ms per frame mean / median: thread CPU time {cm:.3f} / {cmed:.3f} "
              f"(classifier {fm:.3f} / {fmed:.3f}, matches and inputs {rest.mean():.3f} / {np.median(rest):.3f}), "
              f"wall {wm:.3f} / {wmed:.3f}; target <= {TARGET_STAGE_MS:g} ms: "
              f"{'met' if cmed <= TARGET_STAGE_MS else 'NOT met'} (CPU time)")
    return 0


def _scenes(args, stage: dict) -> list:
    """The hook inputs timed: a recorded sequence's (``--sequence``; ``stage`` gets the engine's filter stage
    timings while recording) or toy two-view scenes; what they are is printed."""
    if args.sequence:
        scenes = recorded_inputs(args.sequence, args.sequence_frames, args.masks_kind, stage)
        if not scenes:
            raise D2SlamError("--sequence needs at least 2 frames", path=args.sequence)
        n_masks = [0 if inp.masks is None else len(inp.masks) for inp in scenes]
        n_kps, n_matches = np.mean([len(inp.kps) for inp in scenes]), np.mean([len(inp.matches) for inp in scenes])
        print(f"dynamics bench on {args.sequence}: hook inputs of frames 1-{len(scenes)} (mean {n_kps:.0f} "
              f"keypoints, {n_matches:.0f} matches, {np.mean(n_masks):.1f} masks), {args.frames} timed frames after "
              f"{args.warmup} warm-up, cv2 threads {args.threads}")
    else:
        scenes = []
        for s in range(args.scenes):
            inp, _ = two_view_scene(args.seed + s, n_kps=args.keypoints, n_matches=args.matches,
                                    n_persons=args.masks, frame_index=s + 1)
            scenes.append(inp)
        n_person_px = np.mean([inp.masks.sum() / len(inp.masks) for inp in scenes]) if args.masks else 0
        print(f"dynamics bench: {args.keypoints} keypoints, {args.matches} matches, {args.masks} masks "
              f"(mean {n_person_px:.0f} px each), 640x480, {args.scenes} scenes, {args.frames} timed frames "
              f"after {args.warmup} warm-up, cv2 threads {args.threads}")
    return scenes


def _print_mode(mode: str, res: dict) -> None:
    """A method's timings per stage (mean, median, p95) and the verdicts against the 3 ms target."""
    print(f"\nmethod {mode}                 mean    median     p95   (ms per frame)")
    for k, v in res.items():
        mean, med, p95 = _stats(v)
        print(f"  {k:<22s} {mean:7.3f} {med:9.3f} {p95:7.3f}")
    mean, med, _ = _stats(res["total"])
    cmean, cmed, _ = _stats(res["cpu time (call)"])
    verdict = "meets" if med <= 3.0 else "MISSES"
    cverdict = "meets" if cmed <= 3.0 else "MISSES"
    print(f"  -> total (wall) median {med:.3f} ms, mean {mean:.3f} ms: {verdict} the 3 ms target; "
          f"process CPU time median {cmed:.3f} ms, mean {cmean:.3f} ms: {cverdict} it")
    if "flow" in res:  # the flow is ours, beside the paper's modules (d2slam.dynamics.flow)
        rest = np.asarray(res["total"]) - np.asarray(res["flow"])
        fmean, fmed, _ = _stats(res["flow"])
        print(f"  -> of which the LK flow median {fmed:.3f} ms (mean {fmean:.3f}); the paper's modules without it "
              f"median {np.median(rest):.3f} ms: {'meets' if np.median(rest) <= 3.0 else 'MISSES'} the 3 ms target")


