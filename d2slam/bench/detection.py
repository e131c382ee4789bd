"""``d2slam bench detection``: does the real segmenter (YOLOv8n-seg, ONNX) see the synthetic people?

Renders every ``stride``-th frame of synthetic sequences in memory (the generator's own ``render_frame``: the RGB
as written to ``rgb/``, sensor blur and noise included), segments it, and matches the predicted masks with each
visible person's truth mask. Prints per scenario the detection rate of people covering at least
``SynthConfig.seg_eval_min_area`` of the image (detected: a predicted mask with IoU >= ``seg_eval_iou``; target
>= ``seg_eval_target`` per scenario), false positives (predicted masks matching no person), and the IoU by the
person's median depth. Development seeds only by default (0, 1): the study seeds are never tuned on."""

from __future__ import annotations

import time

import numpy as np

DESCRIPTION = "real segmenter on synthetic people: detection rate (people >= 3 % of the image) and IoU by depth"


def add_arguments(parser) -> None:
    from d2slam.synth.scene import SCENARIOS

    parser.add_argument("--seed", type=int, action="append", help="synthetic seed (repeatable; default 0 and 1)")
    parser.add_argument("--frames", type=int, default=300, help="synthetic sequence length (default 300)")
    parser.add_argument("--stride", type=int, default=10, help="segment every n-th frame (default 10)")
    parser.add_argument("--scenario", action="append", choices=SCENARIOS, help="scenario (repeatable; default all)")
    parser.add_argument("--model", default=None, help="ONNX model (default: the shared 384x512 file)")


def run(args) -> int:
    from d2slam.config import DEFAULT
    from d2slam.eval.segmentation import depth_bin_table, frame_rows, person_ious
    from d2slam.segmentation.onnx import OnnxSegmenter
    from d2slam.synth.generate import render_frame
    from d2slam.synth.realism import sample_indices
    from d2slam.synth.scene import SCENARIOS, Scene
    from d2slam.synth.world import WorldRenderer

    cfg = DEFAULT.synth
    seeds = args.seed or [0, 1]
    seg = OnnxSegmenter(args.model, DEFAULT.segmentation)
    t0 = time.perf_counter()
    print(f"model {seg.model_path.name}, seeds {seeds}, {args.frames} frames every {args.stride}th; people >= "
          f"{100 * cfg.seg_eval_min_area:.0f} % of the image, detected at IoU >= {cfg.seg_eval_iou}")
    print(f"  {'scenario':<20} {'people':>6} {'detected':>8} {'rate':>6}  {'target':<10} {'false pos':>9} "
          f"{'frames':>6}")
    all_rows = []
    for scenario in args.scenario or SCENARIOS:
        rows, fp, n_frames = [], 0, 0
        for seed in seeds:
            scene = Scene(scenario, seed, args.frames, False, cfg)
            renderer = WorldRenderer(scene)
            try:
                for i in sample_indices(args.frames, args.stride):
                    f = render_frame(scene, renderer, int(i))
                    masks = [p.mask for p in seg.segment(f["rgb"])]
                    rows += frame_rows(f["mask_gt"], f["depth_clean"], scene.person_ids, masks)
                    iou = person_ious(f["mask_gt"], scene.person_ids, masks)
                    fp += int((iou.max(axis=0, initial=0.0) < cfg.seg_eval_iou).sum()) if masks else 0
                    n_frames += 1
            finally:
                renderer.close()
        big = [r for r in rows if r["area"] >= cfg.seg_eval_min_area]
        det = sum(r["iou"] >= cfg.seg_eval_iou for r in big)
        rate = det / len(big) if big else float("nan")
        verdict = "met" if rate >= cfg.seg_eval_target else "NOT met"
        print(f"  {scenario:<20} {len(big):>6} {det:>8} {rate:6.3f}  >= {cfg.seg_eval_target:<4} {verdict:<4}"
              f" {fp:>6} {n_frames:>6}")
        all_rows += [dict(r, scenario=scenario) for r in rows]
    depth = np.array([r["depth"] for r in all_rows])
    iou = np.array([r["iou"] for r in all_rows])
    big = np.array([r["area"] >= cfg.seg_eval_min_area for r in all_rows], bool)
    print("IoU by the person's median depth (people >= the area threshold; all visible people in brackets)")
    print(f"  {'depth':<12} {'n':>5} {'mean IoU':>8} {'median':>7}   {'[n':>5} {'mean':>6}]")
    for (label, n, m, md), (_, n_all, m_all, _) in zip(
            depth_bin_table(depth[big], iou[big], cfg.seg_eval_depth_bins),
            depth_bin_table(depth, iou, cfg.seg_eval_depth_bins)):
        print(f"  {label:<12} {n:>5} {m:8.3f} {md:7.3f}   [{n_all:>4} {m_all:6.3f}]")
    print(f"({time.perf_counter() - t0:.1f} s)")
    return 0
