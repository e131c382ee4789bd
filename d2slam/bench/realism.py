"""``d2slam bench realism``: are the synthetic people like real TUM fr3 people, for ORB?

For the five real fr3 walking frames (``d2slam.assets``) (persons from the ONNX segmenter) and for every
``stride``-th frame of each synthetic walking scenario and sitting_static (persons and dynamic pixels from
``mask_gt``), prints the person area fraction, the fraction of the engine's ORB keypoints (ORB-SLAM settings,
1000 features with bucketing) on persons, and their ratio (mean / min / max over the sampled frames). The ratio is
1 when a person is as feature-rich as the rest of the frame. Per frame also the textured share of the image and the
FAST corners (uncapped), the room's realism against the real frames. Calibration targets for the walking scenarios (the
real frames: area 0.10-0.42, ratio 0.1-1.0, mean about 0.4): mean person area 0.2-0.3 with peaks up to about 0.5,
keypoint/area ratio 0.4-0.7 (see ``d2slam.synth.realism``)."""

from __future__ import annotations

import time

import numpy as np

DESCRIPTION = "synthetic vs real TUM people: person area, ORB keypoints on people, their ratio"
TARGET_AREA_MEAN = (0.2, 0.3)
TARGET_AREA_PEAK = 0.55
TARGET_RATIO = (0.4, 0.7)


def add_arguments(parser) -> None:
    from d2slam.synth.scene import SCENARIOS

    parser.add_argument("--seed", type=int, default=0, help="synthetic seed (default 0, a development seed)")
    parser.add_argument("--frames", type=int, default=300, help="synthetic sequence length (default 300)")
    parser.add_argument("--stride", type=int, default=10, help="measure every n-th synthetic frame (default 10)")
    parser.add_argument("--scenario", action="append", choices=SCENARIOS,
                        help="synthetic scenario (repeatable; default: all five)")
    parser.add_argument("--no-real", action="store_true", help="skip the real TUM frames (no ONNX model needed)")


def _row(name: str, area, kp, ratio, n_kp, textured=None, corners=None) -> str:
    from d2slam.synth.realism import summary

    cells = []
    for v in (area, kp, ratio):
        m, lo, hi = summary(v)
        cells.append(f"{m:5.2f} [{lo:4.2f}-{hi:4.2f}]")
    tail = ""
    if textured is not None:
        m, lo, hi = summary(textured)
        c = summary(corners)
        tail = f"  {m:5.2f} [{lo:4.2f}-{hi:4.2f}]  {c[0]:5.0f} [{c[1]:4.0f}-{c[2]:4.0f}]"
    return f"  {name:<34} {len(area):>3}  {cells[0]}  {cells[1]}  {cells[2]}  {np.mean(n_kp):6.0f}{tail}"


def run(args) -> int:
    from d2slam.assets import tum_frames
    from d2slam.synth.realism import extractor, real_stats, summary, synthetic_stats
    from d2slam.synth.scene import SCENARIOS

    t0 = time.perf_counter()
    ext = extractor()
    head = (f"  {'source':<34} {'n':>3}  {'area mean [min-max]':<19}  {'kp on mask':<19}  {'kp/area ratio':<19}"
            f"  {'kp/frame':>6}  {'textured share':<19}  {'FAST corners':<17}")
    print("Person area fraction, fraction of engine ORB keypoints on people, ratio (per frame: mean [min-max])")
    print(head)
    if not args.no_real:
        paths = tum_frames()
        r = real_stats(paths, ext=ext)
        print(_row(r.name, r.area, r.kp, r.ratio, r.n_kp, r.textured, r.corners))
        print("    per frame: " + ", ".join(f"{p.stem[-4:]} {a:.2f}/{k:.2f}" for p, a, k in zip(paths, r.area, r.kp))
              + "  (area/kp)")
    verdicts = []
    for scenario in args.scenario or SCENARIOS:
        s = synthetic_stats(scenario, args.seed, args.frames, args.stride, ext=ext)
        print(_row(f"{scenario} s{args.seed} persons", s.area, s.kp, s.ratio, s.n_kp, s.textured, s.corners))
        print(_row(f"{scenario} s{args.seed} dynamic", s.dyn_area, s.dyn_kp, s.dyn_ratio, s.n_kp))
        if scenario.startswith("walking"):
            am, _, ahi = summary(s.area)
            rm = summary(s.ratio)[0]
            ok = (TARGET_AREA_MEAN[0] <= am <= TARGET_AREA_MEAN[1] and ahi <= TARGET_AREA_PEAK
                  and TARGET_RATIO[0] <= rm <= TARGET_RATIO[1])
            verdicts.append((scenario, ok))
    if verdicts:
        print(f"targets (walking, persons): mean area {TARGET_AREA_MEAN[0]}-{TARGET_AREA_MEAN[1]}, peak <= "
              f"{TARGET_AREA_PEAK}, mean kp/area ratio {TARGET_RATIO[0]}-{TARGET_RATIO[1]}: "
              + ", ".join(f"{n} {'met' if ok else 'NOT met'}" for n, ok in verdicts))
    print(f"({args.frames} frames, every {args.stride}th; {time.perf_counter() - t0:.1f} s)")
    return 0
