"""``d2slam bench masking``: the ways of removing people from a frame for ``orbslam3-masked``
(:mod:`d2slam.baselines.masking`), side by side on synthetic development sequences (seeds 0-99 only: the study
seeds are never tuned on).

Per fill and dilation, on every ``--every``-th frame with people: milliseconds per frame of
:func:`~d2slam.baselines.masking.mask_frame` (median of ``--timing-repeats`` calls, and their minimum: the figure
without other processes taking the cores), and the ORB keypoints (the engine's extractor, ORB-SLAM3's settings) the
masked image gives within ``MaskingConfig.boundary_band_px`` of the region's edge (either side) and deeper inside the
region: keypoints the fill created; and the keypoints left on the people (``mask_gt``) outside the region: what the
masks and the dilation missed. With ``--twin`` the static twin's keypoints in the same band are printed too
(what the scene itself has there). With ``--slam`` each option also runs ORB-SLAM3 on the masked sequences
(``--repeats`` times: median and spread of the ATE).
"""

from __future__ import annotations

import dataclasses
import os
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

from d2slam.baselines.masking import FILLS, boundary_band, keypoints_in, mask_frame
from d2slam.config import DEFAULT
from d2slam.data import open_sequence
from d2slam.errors import D2SlamError
from d2slam.run.orbslam3_runs import run_orbslam3
from d2slam.segmentation import masks_for, stack_masks
from d2slam.slam.frame import OrbExtractor
from d2slam.study.sequences import ensure_sequence

DESCRIPTION = ("orbslam3-masked's fills and dilations on development sequences: ms per frame, ORB keypoints at the "
               "mask boundary, optionally ORB-SLAM3's ATE (--slam)")
SCENARIOS = ("walking_xyz", "walking_static", "sitting_static")


def add_arguments(parser) -> None:
    parser.add_argument("--scenarios", nargs="+", default=list(SCENARIOS), metavar="SCENARIO")
    parser.add_argument("--seeds", nargs="+", type=int, default=[3], metavar="SEED",
                        help="development seeds (0-99; default 3)")
    parser.add_argument("--frames", type=int, default=300, help="frames of each sequence (default 300)")
    parser.add_argument("--every", type=int, default=10, help="every n-th frame is measured (default 10)")
    parser.add_argument("--masks", choices=("onnx", "sim", "gt", "truth"), default="onnx",
                        help="person masks (default onnx, the real segmenter, as for every run)")
    parser.add_argument("--fills", nargs="+", choices=FILLS, default=list(FILLS), metavar="FILL")
    parser.add_argument("--dilate", nargs="+", type=int, default=[0, 2, 4, 8], metavar="PX",
                        help="mask dilations in pixels (default 0 2 4 8)")
    parser.add_argument("--timing-repeats", type=int, default=5, help="timed calls per frame and option (default 5)")
    parser.add_argument("--twin", action="store_true", help="also count the static twins' keypoints in the band "
                        "(generates the twins if not cached)")
    parser.add_argument("--slam", action="store_true", help="also run ORB-SLAM3 on the masked sequences per option")
    parser.add_argument("--repeats", type=int, default=3, help="--slam: ORB-SLAM3 runs per sequence and option")


def _options(args):
    return [dataclasses.replace(DEFAULT.masking, fill=f, dilate_px=d) for d in args.dilate for f in args.fills]


def _label(cfg) -> str:
    return f"{cfg.fill} +{cfg.dilate_px}px"


def measure_frame(rgb, depth, masks, options, extractor, repeats: int, persons=None) -> list[dict]:
    """Per option: ``ms`` (median of ``repeats`` calls), ``ms_min``, ``band`` / ``inside`` keypoint counts, ``left``:
    keypoints on the ``persons`` (H, W) truth outside the region (what the masks and dilation missed), the region's
    band (for the twin's count)."""
    rows = []
    for cfg in options:
        times = []
        for _ in range(max(1, repeats)):
            t = time.perf_counter()
            out_rgb, out_depth, region = mask_frame(rgb, depth, masks, cfg)
            times.append(time.perf_counter() - t)
        kps = extractor(cv2.cvtColor(out_rgb, cv2.COLOR_RGB2GRAY), out_depth).kps_raw
        band = boundary_band(region, cfg.boundary_band_px)
        rows.append({"ms": 1000.0 * float(np.median(times)), "ms_min": 1000.0 * min(times),
                     "band": keypoints_in(band, kps), "inside": keypoints_in(region & ~band, kps), "kps": len(kps),
                     "left": keypoints_in(persons & ~region, kps) if persons is not None else 0,
                     "band_mask": band})
    return rows


def run(args) -> int:
    bad = [s for s in args.seeds if not 0 <= s <= 99]
    if bad:
        raise D2SlamError(f"seeds {bad}: choices are tuned on development seeds 0-99 only")
    if args.every < 1 or args.frames < 2:
        raise D2SlamError("--every must be >= 1 and --frames >= 2")
    cv2.setNumThreads(1)
    options = _options(args)
    stats = {_label(c): {"ms": [], "ms_min": [], "band": [], "inside": [], "kps": [], "left": [], "twin_band": []}
             for c in options}
    n_frames = 0
    for scenario in args.scenarios:
        for seed in args.seeds:
            seq = open_sequence(ensure_sequence(scenario, seed, args.frames, False))
            twin = open_sequence(ensure_sequence(scenario, seed, args.frames, True)) if args.twin else None
            extractor = OrbExtractor(DEFAULT.orb, DEFAULT.engine, seq.camera)
            shape = (seq.camera.height, seq.camera.width)
            for i in range(0, len(seq), args.every):
                masks = stack_masks(masks_for(seq, i, args.masks), shape)
                if not masks.any():
                    continue
                frame = seq[i]
                persons = stack_masks(masks_for(seq, i, "gt"), shape).any(axis=0)
                rows = measure_frame(frame.rgb, frame.depth, masks, options, extractor, args.timing_repeats, persons)
                twin_kps = None
                if twin is not None:
                    tf = twin[i]
                    twin_kps = extractor(cv2.cvtColor(tf.rgb, cv2.COLOR_RGB2GRAY), tf.depth).kps_raw
                n_frames += 1

                for cfg, row in zip(options, rows):
                    s = stats[_label(cfg)]
                    for k in ("ms", "ms_min", "band", "inside", "kps", "left"):
                        s[k].append(row[k])
                    if twin_kps is not None:
                        s["twin_band"].append(keypoints_in(row["band_mask"], twin_kps))
    if not n_frames:
        raise D2SlamError("no measured frame has people: nothing to mask")
    print(f"machine: {os.cpu_count()} CPUs, load average (1 min) {os.getloadavg()[0]:.1f}; {n_frames} frames with "
          f"people ({', '.join(args.scenarios)}; seeds {' '.join(map(str, args.seeds))}; every {args.every}th of "
          f"{args.frames}), {args.masks} masks, band {DEFAULT.masking.boundary_band_px} px")
    twin_col = f" {'twin band':>9s}" if args.twin else ""
    print(f"{'option':16s} {'ms/frame':>8s} {'ms min':>7s} {'band kps':>8s} {'inside':>7s} {'all kps':>7s} "
          f"{'on persons':>10s}{twin_col}")
    for cfg in options:
        s = stats[_label(cfg)]
        twin_val = f" {np.mean(s['twin_band']):9.1f}" if args.twin else ""
        print(f"{_label(cfg):16s} {np.mean(s['ms']):8.2f} {np.mean(s['ms_min']):7.2f} {np.mean(s['band']):8.1f} "
              f"{np.mean(s['inside']):7.1f} {np.mean(s['kps']):7.0f} {np.mean(s['left']):10.1f}{twin_val}")
    print("(keypoints per frame: mean; on persons: keypoints on the persons of mask_gt left outside the region; "
          "ms/frame: mean over frames of the median of the timed calls, ms min: of their minimum)")
    if args.slam:
        _slam(args, options)
    return 0


def _slam(args, options) -> None:
    """ORB-SLAM3 on each masked sequence per option: ATE median [min, max] over ``--repeats``, tracked frames."""
    seqs = [(sc, sd) for sc in args.scenarios for sd in args.seeds]
    print(f"\nORB-SLAM3 on the masked sequences ({args.masks} masks, {args.repeats} repeats): ATE mm median "
          "[min, max], tracked frames (median)")
    print(f"{'option':16s} " + " ".join(f"{f'{sc[:14]} s{sd}':>26s}" for sc, sd in seqs) + f" {'sum of medians':>15s}")
    with tempfile.TemporaryDirectory(prefix="d2slam_bench_masking_") as tmp:
        for cfg in options:
            config = dataclasses.replace(DEFAULT, masking=cfg)
            cells, total = [], 0.0
            for sc, sd in seqs:
                path = ensure_sequence(sc, sd, args.frames, False)
                run = run_orbslam3(path, Path(tmp) / "t.txt", repeats=args.repeats, config=config, progress=False,
                                   masks=args.masks)
                m, spread = run.get("metrics") or {}, (run.get("metrics_spread") or {}).get("ate_rmse_m")
                if "ate_rmse_m" in m:
                    lo, hi = (spread["min"], spread["max"]) if spread else (m["ate_rmse_m"], m["ate_rmse_m"])
                    cells.append(f"{1000 * m['ate_rmse_m']:.1f} [{1000 * lo:.1f}, {1000 * hi:.1f}] "
                                 f"{run.get('tracked', 0):.0f}")
                    total += 1000 * m["ate_rmse_m"]
                else:
                    cells.append(f"{run.get('status')}")
                    total = float("nan")
            print(f"{_label(cfg):16s} " + " ".join(f"{c:>26s}" for c in cells) + f" {total:15.1f}", flush=True)
