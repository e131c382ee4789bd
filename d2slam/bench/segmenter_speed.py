"""``d2slam bench segmenter_speed``: frames per second of the ONNX person segmenter, per model, with the time split
into preprocess (resize, scale, NCHW), inference (onnxruntime) and postprocess (decode, NMS, masks at frame size),
on the five real TUM frames (``d2slam.assets``) repeated. Targets: >= 20 fps at 256x320, >= 15 fps at 384x512.

``--cache SEQ`` times instead what a ``--masks onnx`` run pays per frame once the sequence is segmented: reading a
frame's persons from the mask cache and stacking them into the hook's (n, H, W) masks (``masks_for`` +
``stack_masks``, the pipeline's mask provider), over every frame of SEQ (segmented first when the cache misses
frames). The first pass opens the cache (a new process's first run); later passes reuse it. Target: <= 1 ms per
frame."""

from __future__ import annotations

import dataclasses
import os
import time
from pathlib import Path

import numpy as np

from d2slam.assets import asset_path, tum_frames
from d2slam.config import DEFAULT
from d2slam.data import open_sequence
from d2slam.segmentation import CachedSegmenter, get_segmenter, stack_masks
from d2slam.segmentation.onnx import KNOWN_MODELS, OnnxSegmenter, read_rgb

DESCRIPTION = ("segmenter speed per model (fps; ms split preprocess / inference / postprocess) on the five real "
               "TUM frames repeated")
TARGET_FPS = {"yolov8n-seg_deq_256x320.onnx": 20.0, "yolov8n-seg_deq_384x512.onnx": 15.0}


def add_arguments(parser) -> None:
    parser.add_argument("--repeats", type=int, default=20, help="passes over the five frames (default 20)")
    parser.add_argument("--warmup", type=int, default=3, help="untimed frames first (default 3)")
    parser.add_argument("--model", action="append", metavar="PATH",
                        help="model file (repeatable; default: the three known models)")
    parser.add_argument("--threads", type=int, help="onnxruntime intra-op threads (default: the config's)")
    parser.add_argument("--cache", metavar="SEQ", help="time reading SEQ's cached masks per frame instead (segments "
                        "the frames not cached yet first; --repeats passes)")


def run(args) -> int:
    if args.cache:
        return cache_read(args)

    images = tum_frames()
    frames = [read_rgb(p) for p in images]
    models = [Path(m) for m in args.model] if args.model else [
        asset_path(f"models/{name}") for name in sorted(KNOWN_MODELS.values(), reverse=True)]
    cfg = DEFAULT.segmentation
    if args.threads:
        cfg = dataclasses.replace(cfg, intra_op_threads=args.threads)
    n = len(frames) * max(1, args.repeats)
    print(f"machine: {os.cpu_count()} CPUs, load average (1 min) at start {os.getloadavg()[0]:.1f} "
          "(other processes share the cores: compare runs at similar load)")
    print(f"{len(frames)} frames of {frames[0].shape[1]}x{frames[0].shape[0]} x {max(1, args.repeats)} = {n} "
          f"timed frames per model, intra_op_threads={cfg.intra_op_threads}")
    print(f"{'model':32s} {'input':>8s} {'fps':>6s} {'total ms':>9s} {'pre':>6s} {'infer':>6s} {'post':>6s}  "
          f"{'persons':>7s}  target")
    for path in models:
        seg = OnnxSegmenter(path, cfg)
        for i in range(args.warmup):
            seg.segment(frames[i % len(frames)])
        split = np.zeros((n, 3))
        persons = 0
        t0 = time.perf_counter()
        for i in range(n):
            persons += len(seg.segment(frames[i % len(frames)]))
            split[i] = seg.timings
        total = time.perf_counter() - t0
        fps = n / total
        ms = split.mean(axis=0) * 1000
        target = TARGET_FPS.get(path.name)
        verdict = "-" if target is None else f">= {target:.0f} fps: {'met' if fps >= target else 'NOT met'}"
        h, w = seg.input_hw
        print(f"{path.name:32s} {f'{h}x{w}':>8s} {fps:6.1f} {1000 * total / n:9.1f} {ms[0]:6.1f} {ms[1]:6.1f} "
              f"{ms[2]:6.1f}  {persons / max(1, args.repeats):7.0f}  {verdict}")
    print(f"load average (1 min) at end {os.getloadavg()[0]:.1f}")
    return 0


TARGET_READ_MS = 1.0


def cache_read(args) -> int:
    """Milliseconds per frame of the pipeline's mask provider on a segmented sequence (module docstring)."""
    model = args.model[0] if args.model else None
    seq = open_sequence(args.cache)
    seg = get_segmenter("onnx", config=DEFAULT.segmentation, model=model)
    hits, misses = CachedSegmenter(seg, seq).fill()
    shape = (seq.camera.height, seq.camera.width)
    n = len(seq)
    print(f"machine: {os.cpu_count()} CPUs, load average (1 min) {os.getloadavg()[0]:.1f}; {seq.root}: {n} frames "
          f"({misses} segmented now), model {seg.model_path.name}")
    print(f"{'pass':<28s} {'ms/frame':>8s} {'cpu ms':>7s} {'persons':>7s}  target")
    cached = None
    for rep in range(max(1, args.repeats)):
        c0, t0 = time.process_time(), time.perf_counter()
        if cached is None:
            cached = CachedSegmenter(seg, seq)
        persons = 0
        for i in range(n):
            persons += len(stack_masks(cached.instances(i), shape))
        wall, cpu = (time.perf_counter() - t0) * 1e3 / n, (time.process_time() - c0) * 1e3 / n
        label = "1 (opens the cache)" if rep == 0 else str(rep + 1)
        verdict = f"<= {TARGET_READ_MS:g} ms: {'met' if wall <= TARGET_READ_MS else 'NOT met'}"
        print(f"{label:<28s} {wall:8.3f} {cpu:7.3f} {persons / n:7.2f}  {verdict}")
    return 0
