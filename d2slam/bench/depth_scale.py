"""``d2slam bench depth_scale SEQ...``: the depth-scale check of ``d2slam run`` on sequences read with the right depth
factor, with every depth 5 times too large (the factor / 5) and 5 times too small (the factor x 5, e.g. millimetres
read with TUM's 5000).

Per sequence and scale: the ratios of the camera translation measured through the depth to the ground truth's on
each frame pair (:func:`d2slam.data.depth_scale.translation_ratios`; none when the camera does not move enough: the
indoor-depth fallback then decides), whether ``d2slam run`` would warn, and the check's time."""

from __future__ import annotations

import dataclasses
import time

from d2slam.data import open_sequence
from d2slam.data.depth_scale import depth_scale_warning, translation_ratios
from d2slam.data.tum import TumSequence

DESCRIPTION = "depth-scale check on sequences read right, x5 and x0.2: ratio to the ground truth, verdict, time"


def add_arguments(parser) -> None:
    parser.add_argument("sequences", nargs="+", metavar="SEQ", help="TUM-layout or synthetic sequence folders")


def run(args) -> int:
    print(f"  {'sequence':<44} {'scale':>5}  {'ratios':<24} {'warns':<5} {'time':>6}")
    wrong = 0
    for path in args.sequences:
        base = open_sequence(path)
        for scale in (1.0, 5.0, 0.2):
            seq = TumSequence(path, camera=dataclasses.replace(base.camera,
                                                              depth_factor=base.camera.depth_factor / scale))
            t0 = time.perf_counter()
            warned = depth_scale_warning(seq) is not None  # what `d2slam run` does, timed
            dt = time.perf_counter() - t0
            ratios = translation_ratios(seq)
            wrong += warned != (scale != 1.0)
            shown = " ".join(f"{r:.2f}" for r in ratios) or "(no pair: fallback)"
            print(f"  {base.name[:44]:<44} {scale:>5g}  {shown:<24} {'yes' if warned else 'no':<5} {dt:>5.2f}s")
    print(f"{wrong} wrong verdicts (a warning at the right scale, or none at x5 / x0.2)")
    return 0 if wrong == 0 else 1
