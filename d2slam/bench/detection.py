"""``d2slam bench detection``: does the real segmenter (YOLOv8n-seg, ONNX) see the synthetic people?

Renders every ``stride``-th frame of synthetic sequences in memory (the generator's own ``render_frame``: the RGB
as written to ``rgb/``, sensor blur and noise included), segments it, and matches the predicted masks with each
visible person's truth mask. Prints per scenario the detection rate of people covering at least
``SynthEvalConfig.seg_eval_min_area`` of the image (detected: a predicted mask with IoU >= ``seg_eval_iou``; target
>= ``seg_eval_target`` per scenario), false positives (predicted masks matching no person), and the IoU by the
person's median depth, and the boundary error of detected people (``eval.segmentation.boundary_error``) by depth
beside eq 2's uncertainty half-width ln 3 / beta(z) at their depth, with the share of people whose boundary error
(90th percentile) lies within it. Development seeds only by default (0, 1): the study seeds are never tuned on."""

from __future__ import annotations

import time

import numpy as np

from d2slam.config import DEFAULT
from d2slam.eval.segmentation import boundary_table, depth_bin_table, synthetic_rows
from d2slam.segmentation.onnx import OnnxSegmenter
from d2slam.synth.scene import SCENARIOS

DESCRIPTION = ("real segmenter on synthetic people: detection rate (people >= 3 % of the image), IoU and boundary "
               "error by depth")


def add_arguments(parser) -> None:
    parser.add_argument("--seed", type=int, action="append", help="synthetic seed (repeatable; default 0 and 1)")
    parser.add_argument("--frames", type=int, default=300, help="synthetic sequence length (default 300)")
    parser.add_argument("--stride", type=int, default=10, help="segment every n-th frame (default 10)")
    parser.add_argument("--scenario", action="append", choices=SCENARIOS, help="scenario (repeatable; default all)")
    parser.add_argument("--model", default=None, help="ONNX model (default: the shared 384x512 file)")


def run(args) -> int:
    cfg = DEFAULT.synth_eval
    seeds = args.seed or [0, 1]
    seg = OnnxSegmenter(args.model, DEFAULT.segmentation)
    t0 = time.perf_counter()
    print(f"model {seg.model_path.name}, seeds {seeds}, {args.frames} frames every {args.stride}th; people >= "
          f"{100 * cfg.seg_eval_min_area:.0f} % of the image, detected at IoU >= {cfg.seg_eval_iou}")
    print(f"  {'scenario':<20} {'people':>6} {'detected':>8} {'rate':>6}  {'target':<10} {'false pos':>9} "
          f"{'frames':>6}")
    all_rows = []
    for scenario in args.scenario or SCENARIOS:
        rows, frames = synthetic_rows([(scenario, s, args.frames, args.stride) for s in seeds], seg, DEFAULT)
        big = [r for r in rows if r["area"] >= cfg.seg_eval_min_area]
        det = sum(r["iou"] >= cfg.seg_eval_iou for r in big)
        rate = det / len(big) if big else float("nan")
        verdict = "met" if rate >= cfg.seg_eval_target else "NOT met"
        print(f"  {scenario:<20} {len(big):>6} {det:>8} {rate:6.3f}  >= {cfg.seg_eval_target:<4} {verdict:<4}"
              f" {sum(f['false_pos'] for f in frames):>6} {len(frames):>6}")
        all_rows += rows
    depth = np.array([r["depth"] for r in all_rows])
    iou = np.array([r["iou"] for r in all_rows])
    big = np.array([r["area"] >= cfg.seg_eval_min_area for r in all_rows], bool)
    print("IoU by the person's median depth (people >= the area threshold; all visible people in brackets)")
    print(f"  {'depth':<12} {'n':>5} {'mean IoU':>8} {'median':>7}   {'[n':>5} {'mean':>6}]")
    for (label, n, m, md), (_, n_all, m_all, _) in zip(
            depth_bin_table(depth[big], iou[big], cfg.seg_eval_depth_bins),
            depth_bin_table(depth, iou, cfg.seg_eval_depth_bins)):
        print(f"  {label:<12} {n:>5} {m:8.3f} {md:7.3f}   [{n_all:>4} {m_all:6.3f}]")
    q = f"p{cfg.seg_eval_boundary_percentile:g}"
    print(f"Boundary error (px) of detected people >= the area threshold by median depth: median over people of the "
          f"mean and {q} of the symmetric boundary distances; band = eq 2's uncertainty half-width ln 3 / beta(z) at "
          f"their depth (median); share of people whose {q} is within their band")
    print(f"  {'depth':<12} {'n':>5} {'mean':>6} {q:>6} {'band':>6} {'within':>7}")
    for label, n, b_mean, b_q, width, share in boundary_table(all_rows, DEFAULT):
        print(f"  {label:<12} {n:>5} {b_mean:6.2f} {b_q:6.2f} {width:6.2f} {share:7.3f}")
    print(f"({time.perf_counter() - t0:.1f} s)")
    return 0
