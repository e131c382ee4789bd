"""``d2slam bench realism``: are the synthetic people like real TUM fr3 people, for ORB?

For the five real fr3 walking frames (``d2slam.assets``) (persons from the ONNX segmenter) and for every
``stride``-th frame of each synthetic walking scenario and sitting_static (persons and dynamic pixels from
``mask_gt``), prints the person area fraction, the fraction of the engine's ORB keypoints (ORB-SLAM settings,
1000 features with bucketing) on persons, and their ratio (mean / min / max over the sampled frames). The ratio is
1 when a person is as feature-rich as the rest of the frame. Per frame also the textured share of the image and the
FAST corners (uncapped), the room's realism against the real frames. Calibration targets for the walking scenarios (the
real frames: area 0.10-0.42, ratio 0.1-1.0, mean about 0.4): mean person area 0.2-0.3 with peaks up to about 0.5,
keypoint/area ratio 0.4-0.7 (see ``d2slam.synth.realism``).

The sensor, real against synthetic (``d2slam.eval.realism``; docs/real_data.md, "The synthetic twin and the sensor
model"):

- ``--real SEQ --twin SEQ``: a real recording and a synthetic sequence (its twin) side by side, each run through the
  engine with nothing filtered: FAST corners, image noise, the static matches' epipolar error (eq 5) percentiles
  overall, by depth, by image radius and by angular speed, the pose test's residuals, track lengths, depth holes,
  blur, angular speed; and the twin's target (epipolar p50 and p90 within 25 % of the real's);
- ``--calibrate SEQ``: the sensor measurements of a real recording that ``SynthConfig.twin`` holds (exposure, time
  offset and rolling shutter, depth border, RGB-depth offsets, image noise);
- ``--anchor SEQ``: where the recording goes in the room (``TwinConfig.anchor_xy``, ``anchor_heading_deg``): the
  twin's depth percentiles against the real ones over a grid of placements.

People composited into a real recording (``d2slam.eval.people_realism``; docs/real_people.md):

- ``--composite SEQ`` (repeatable; ``d2slam synth real_walking --on TUM_DIR``): the real segmenter's detection rate
  of the composited people covering at least ``seg_eval_min_area`` of the image (target ``seg_eval_target``) and
  their IoU by depth against the synthetic office's people (walking scenarios, development seeds, rendered in
  memory) at matched distance and coverage (target: within ``COMPOSITE_IOU_TOLERANCE`` per depth bin); the same by
  the camera's roll, and with every frame turned upright."""

from __future__ import annotations

import time

import numpy as np

from d2slam.assets import tum_frames
from d2slam.config import DEFAULT
from d2slam.data import open_sequence
from d2slam.data.tum import interpolate_poses
from d2slam.errors import D2SlamError
from d2slam.eval.people_realism import column, composite_coverage, composite_rows, matched, office_rows
from d2slam.eval.realism import (anchor_scan, comparison, depth_border, depth_consistency, edge_hole_runs, fit_exposure,
                                 fit_time_offset, frame_blur, hole_kinds, measure, noise_sigma, pct, within)
from d2slam.eval.segmentation import depth_bin_table
from d2slam.run.observe import engine_log
from d2slam.segmentation.onnx import OnnxSegmenter
from d2slam.synth.realism import extractor, real_stats, summary, synthetic_stats
from d2slam.synth.scene import SCENARIOS
from d2slam.synth.twin import read_recording

DESCRIPTION = ("synthetic vs real TUM people: person area, ORB keypoints on people, their ratio; the sensor, real "
               "against its synthetic twin (--real/--twin, --calibrate, --anchor)")
TWIN_TOLERANCE = 0.25  # the twin's epipolar p50 and p90 within this fraction of the real recording's
TARGET_AREA_MEAN = (0.2, 0.3)
TARGET_AREA_PEAK = 0.55
TARGET_RATIO = (0.4, 0.7)
COMPOSITE_IOU_TOLERANCE = 0.1  # a composite's mean IoU per depth bin within this of the synthetic office's
OFFICE_SCENARIOS = ("walking_xyz", "walking_halfsphere", "walking_static", "walking_rpy")
ROLL_BINS = (15.0, 30.0, 45.0)  # |roll| (degrees) bins of the detection rates


def add_arguments(parser) -> None:
    parser.add_argument("--seed", type=int, default=0, help="synthetic seed (default 0, a development seed)")
    parser.add_argument("--frames", type=int, default=None,
                        help="synthetic sequence length (default 300); with --real/--twin/--calibrate the frames "
                        "measured (default 200)")
    parser.add_argument("--stride", type=int, default=10, help="measure every n-th synthetic frame (default 10)")
    parser.add_argument("--scenario", action="append", choices=SCENARIOS,
                        help="synthetic scenario (repeatable; default: all five)")
    parser.add_argument("--no-real", action="store_true", help="skip the real TUM frames (no ONNX model needed)")
    parser.add_argument("--real", metavar="SEQ", help="a real TUM recording to compare with --twin (the sensor)")
    parser.add_argument("--twin", metavar="SEQ", help="a synthetic sequence (its twin) to compare with --real")
    parser.add_argument("--calibrate", metavar="SEQ", help="measure a real recording's sensor (SynthConfig.twin)")
    parser.add_argument("--anchor", metavar="SEQ", help="scan the twin's placement in the room against a real "
                        "recording's depths (its first 120 frames, every 10th)")
    parser.add_argument("--composite", metavar="SEQ", action="append",
                        help="a composite (d2slam synth real_walking --on TUM_DIR; repeatable): the real segmenter on "
                        "its people against the synthetic office's at matched depth and coverage (the office's walking "
                        "scenarios with --seed, default 0 and 1, --frames 300, every --stride-th frame; the "
                        "composites every --composite-stride-th)")
    parser.add_argument("--composite-stride", type=int, default=5, help="segment every n-th composite frame "
                        "(default 5)")
    parser.add_argument("--model", default=None, help="--composite: the ONNX model (default: the study's)")


def _row(name: str, area, kp, ratio, n_kp, textured=None, corners=None) -> str:
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
    if args.composite:
        return run_composite(args)
    if args.real or args.twin:
        return run_compare(args)
    if args.calibrate:
        return run_calibrate(args)
    if args.anchor:
        return run_anchor(args)
    return run_people(args)


def run_compare(args) -> int:
    if not (args.real and args.twin):
        raise D2SlamError("--real and --twin go together: a real recording and its synthetic twin")
    t0 = time.perf_counter()
    frames = args.frames or 200
    real, twin = open_sequence(args.real), open_sequence(args.twin)
    r = measure(real, engine_log(real, frames, progress=True))
    s = measure(twin, engine_log(twin, frames, progress=True))
    rows = comparison(r, s)
    w = max(len(a) for a, _, _ in rows) + 2
    w2 = max([len(a) for _, a, _ in rows] + [len(r.name) + 6]) + 2
    print(f"The sensor, real against synthetic: first {frames} frames, the engine with nothing filtered (as --method "
          "none), its frame-to-frame matches as the geometric module sees them")
    print(f"  {'':<{w}}{'real: ' + r.name:<{w2}}{'synthetic: ' + s.name}")
    for what, a, b in rows:
        print(f"  {what:<{w}}{a:<{w2}}{b}")
    er, es = pct(r.matches.epi, (50, 90)), pct(s.matches.epi, (50, 90))
    ok = [within(a, b, TWIN_TOLERANCE) for a, b in zip(er, es)]
    print(f"target: the synthetic sequence's epipolar p50 and p90 within {100 * TWIN_TOLERANCE:.0f} % of the real's: "
          f"p50 {es[0]:.2f} vs {er[0]:.2f} ({100 * (es[0] / er[0] - 1):+.0f} %) {'met' if ok[0] else 'NOT met'}, "
          f"p90 {es[1]:.2f} vs {er[1]:.2f} ({100 * (es[1] / er[1] - 1):+.0f} %) {'met' if ok[1] else 'NOT met'}")
    print(f"({time.perf_counter() - t0:.1f} s)")
    return 0


def run_calibrate(args) -> int:
    """The real recording's sensor, as ``SynthConfig.twin`` holds it (docs/real_data.md)."""
    t0 = time.perf_counter()
    seq = open_sequence(args.calibrate)
    if seq.groundtruth is None:
        raise D2SlamError("the recording has no ground truth: the calibration measures against it", path=seq.root)
    n = min(len(seq), args.frames or 200)
    tw = DEFAULT.synth.twin
    print(f"The sensor of {seq.name} (camera {seq.camera.name}), first {n} frames; SynthConfig.twin in brackets")
    ts, dts = np.asarray(seq.timestamps[:n]), np.asarray(seq.depth_timestamps[:n])
    off = 1e3 * (dts - ts)
    print(f"  depth timestamp - RGB timestamp (ms): median |.| {np.median(np.abs(off)):.1f}, min {off.min():.1f}, "
          f"max {off.max():.1f} [depth rendered at its own timestamp: {tw.depth_at_depth_time}]")
    best_o = _calibrate_rgb_time(seq, n, tw)
    _calibrate_depth_time(seq, n, tw)
    depths, noise = _calibrate_blur(seq, n, best_o, tw)
    _calibrate_holes(depths, noise, tw)
    print(f"({time.perf_counter() - t0:.1f} s)")
    return 0


def _calibrate_rgb_time(seq, n: int, tw) -> float:
    """The RGB images' time shift and row readout by the epipolar error against the ground truth's motion, printed
    as a table; the best shift."""
    log = engine_log(seq, n, progress=True)
    offsets = np.round(np.arange(-0.012, 0.0121, 0.002), 4)
    readouts = np.round(np.arange(0.0, 8.1e-5, 2e-5), 7)
    table, best_o, best_r = fit_time_offset(log, seq, offsets, readouts)
    print("  median epipolar error (px) of the matches against the ground truth's motion, by time offset (rows, ms) "
          "and row readout (columns, us/row):")
    print("           " + " ".join(f"{1e6 * r:6.0f}" for r in readouts))
    for o, line in zip(offsets, table):
        print(f"    {1e3 * o:+6.1f} " + " ".join(f"{v:6.3f}" for v in line))
    print(f"  best: RGB time shift {1e3 * best_o:+.1f} ms [{1e3 * tw.rgb_time_shift:+.1f}], readout "
          f"{1e6 * best_r:.0f} us/row [{1e6 * tw.row_readout:.0f}]; the readout's gain over a global shutter: "
          f"{table[list(offsets).index(best_o), 0] - table.min():.3f} px")
    return best_o


def _calibrate_depth_time(seq, n: int, tw) -> None:
    """The depth images' time shift and row readout by the agreement of one frame's depth moved into the next,
    printed as a table."""
    shifts = np.round(np.arange(-0.03, -0.0149, 0.0025), 4)
    dreadouts = np.round(np.arange(0.0, 1.01e-4, 2.5e-5), 7)
    cons = np.array([[float(np.nanmean(depth_consistency(seq, np.arange(1, n), float(o), readout=float(r))))
                      for r in dreadouts] for o in shifts])
    print("  depth of one frame moved into the next by the ground truth's motion, mean over frames of the median "
          "|dz| / sigma, by the depth images' time shift (rows, ms) and row readout (columns, us/row):")
    print("           " + " ".join(f"{1e6 * r:6.0f}" for r in dreadouts))
    for o, line in zip(shifts, cons):
        print(f"    {1e3 * o:+6.1f} " + " ".join(f"{v:6.3f}" for v in line))
    i, j = np.unravel_index(int(np.argmin(cons)), cons.shape)
    print(f"  best: depth time shift {1e3 * shifts[i]:+.1f} ms [{1e3 * tw.depth_time_shift:+.1f}], readout "
          f"{1e6 * dreadouts[j]:.0f} us/row [{1e6 * tw.depth_row_readout:.0f}]; the readout's gain over a global "
          f"shutter: {cons[:, 0].min() - cons.min():.3f}")


def _calibrate_blur(seq, n: int, best_o: float, tw) -> tuple[list, list]:
    """The exposure from the motion blur's extent against the image speed (every second frame), printed; (those
    frames' depth images, their image noise)."""
    gt = seq.groundtruth

    def poses_at(t):
        return interpolate_poses(gt.timestamps, gt.poses, np.clip(np.asarray(t) + best_o, gt.timestamps[0],
                                                                 gt.timestamps[-1]), max_gap=None)

    speed, ext, depths, noise = [], [], [], []
    for i in range(0, n, 2):
        f = seq[i]
        sp, ex = frame_blur(f.gray, f.depth, seq.camera, poses_at, f.timestamp)
        speed.append(sp)
        ext.append(ex)
        depths.append(f.depth)
        noise.append(noise_sigma(f.gray))
    speed, ext = np.concatenate(speed), np.concatenate(ext)
    e, b, used = fit_exposure(speed, ext)
    print(f"  blur extent (px) against image speed (px/s), median per speed bin:")
    for lo, hi in ((0, 200), (200, 400), (400, 600), (600, 800), (800, 1000), (1000, 1500)):
        sel = (speed >= lo) & (speed < hi) & np.isfinite(ext)
        print(f"    {lo:5d}-{hi:<5d} {int(sel.sum()):5d} patches  {np.median(ext[sel]) if sel.any() else np.nan:5.1f}")
    print(f"  exposure (Theil-Sen slope over {used} patches): {1e3 * e:.1f} ms [{1e3 * tw.exposure:.1f}], intercept "
          f"{b:.1f} px")
    return depths, noise


def _calibrate_holes(depths: list, noise: list, tw) -> None:
    """The depth border, the holes at depth edges and elsewhere, the image noise, printed."""
    border = depth_border(depths)
    print(f"  depth border (top, bottom, left, right px, holes in >= half): {border} [{tw.depth_border}]")
    t_, b_, l_, r_ = border
    inner = [d[t_:d.shape[0] - b_, l_:d.shape[1] - r_] for d in depths]
    print(f"  depth holes: whole image {100 * np.mean([np.mean(d <= 0) for d in depths]):.1f} %, inside the border "
          f"{100 * np.mean([np.mean(d <= 0) for d in inner]):.1f} %")
    syn = DEFAULT.synth
    kinds = [hole_kinds(d, border, syn.hole_edge_jump_a, syn.hole_edge_jump_b) for d in depths]
    runs = [edge_hole_runs(d, border, syn.hole_edge_jump_a, syn.hole_edge_jump_b) for d in depths]
    right, left = (np.concatenate([r[k] for r in runs]) for k in (0, 1))
    print(f"  inside the border, holes at depth edges {100 * np.median([k['edge'] for k in kinds]):.1f} %, other "
          f"holes {100 * np.median([k['blob'] for k in kinds]):.2f} % of the image (medians over frames) "
          f"[hole_blob_fraction {100 * tw.hole_blob_fraction:.2f} %]; hole runs along the rows at depth edges: nearer "
          f"surface on the right {np.median(right) if right.size else np.nan:.0f} px ({right.size} runs) "
          f"[shadow_px {tw.shadow_px}], on the left {np.median(left) if left.size else np.nan:.0f} px ({left.size})")
    print(f"  image noise (grey levels) p10/p50/p90: {'/'.join(f'{v:.2f}' for v in pct(noise, (10, 50, 90)))} "
          f"[the twin's rgb_noise_sigma {tw.rgb_noise_sigma}: reads 0.49 on its images]")


def run_anchor(args) -> int:
    """The twin's placement: its depth percentiles against the recording's over a grid of anchors."""
    t0 = time.perf_counter()
    rec, seq = read_recording(args.anchor), open_sequence(args.anchor)
    idx = np.arange(0, min(len(rec), 120), 10)
    rows = anchor_scan(rec, [seq[int(i)].depth for i in idx], idx, np.round(np.arange(-0.3, 1.81, 0.15), 2),
                       np.round(np.arange(2.5, 3.11, 0.1), 2), (70, 80, 90, 100, 110, 120))
    tw = DEFAULT.synth.twin
    print(f"The twin's placement: depth percentiles 10/25/50/75/90 (m) of frames {idx[0]}-{idx[-1]} (every 10th), "
          f"real {'/'.join(f'{v:.2f}' for v in rows[0]['real'])}; best of {len(rows)} anchors (first pose's x, y m, "
          f"heading deg) [config: {tw.anchor_xy}, {tw.anchor_heading_deg}]:")
    for r in rows[:10]:
        print(f"  x {r['x']:5.2f} y {r['y']:5.2f} heading {r['heading']:5.0f}: "
              f"{'/'.join(f'{v:.2f}' for v in r['twin'])}  mismatch {r['mismatch']:.3f}")
    print(f"({time.perf_counter() - t0:.1f} s)")
    return 0


def run_people(args) -> int:
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
    frames = args.frames or 300
    for scenario in args.scenario or SCENARIOS:
        s = synthetic_stats(scenario, args.seed, frames, args.stride, ext=ext)
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
    print(f"({frames} frames, every {args.stride}th; {time.perf_counter() - t0:.1f} s)")
    return 0


def run_composite(args) -> int:
    """The real segmenter on composited people against the synthetic office's (module docstring)."""
    t0 = time.perf_counter()
    ev = DEFAULT.synth_eval
    seqs, seg, comp, office, office_seeds = _composite_rows(args)
    lo, thr = ev.seg_eval_min_area, ev.seg_eval_iou
    print(f"The real segmenter ({seg.model_path.name}) on people composited into a real recording against the "
          f"synthetic office's; people covering >= {100 * lo:g} % of the image, detected at IoU >= {thr:g}")
    print(f"  composites: {', '.join(q.root.name for q in seqs)}, every {args.composite_stride}th frame; office: "
          f"{', '.join(args.scenario or OFFICE_SCENARIOS)}, seeds {office_seeds}, {args.frames or 300} frames, every "
          f"{args.stride}th")
    _print_people_in_view(seqs, comp, office)
    verdicts = [_print_detection(seqs, comp, office, lo, thr, ev.seg_eval_target)]
    _print_by_roll(comp, office, lo, thr)
    ok_all = _print_iou_by_depth(comp, office, lo, ev.seg_eval_depth_bins)
    for key, what in (("iou", "as recorded"), ("iou_upright", "upright"), ("iou_isolated", "isolated")):
        m = matched(comp, office, ev.seg_eval_depth_bins, key, lo, thr)
        print(f"  matched distance and coverage ({what}): {m['people']} composited people ({m['unmatched']} in cells "
              f"the office lacks): detection {m['composite_rate']:.3f} against the office's {m['office_rate']:.3f}, "
              f"mean IoU {m['composite_mean']:.3f} against {m['office_mean']:.3f}")
    verdicts.append(f"IoU by depth within {COMPOSITE_IOU_TOLERANCE:g} of the office's: {'met' if ok_all else 'NOT met'}")
    print("targets: " + "; ".join(verdicts))
    print(f"({time.perf_counter() - t0:.1f} s)")
    return 0


def _composite_rows(args) -> tuple:
    """(the composites, the segmenter, its rows on the composites, its rows on the synthetic office, the office's
    seeds): the people of every ``--composite-stride``-th composite frame and of the office's frames, segmented."""
    seqs = [open_sequence(p) for p in args.composite]
    for q in seqs:
        if not (q.root / "mask_depth").is_dir():
            raise D2SlamError("not a composite (no mask_depth/): make one with d2slam synth real_walking --on "
                              "TUM_DIR", path=q.root)
    seg = OnnxSegmenter(args.model, DEFAULT.segmentation)
    segment = seg.segment
    comp = []
    for q in seqs:
        comp += [dict(r, sequence=q.root.name) for r in composite_rows(q, segment, args.composite_stride)]
    office_seeds = [args.seed] if args.seed else [0, 1]
    office = office_rows(args.scenario or OFFICE_SCENARIOS, office_seeds, args.frames or 300, args.stride, segment,
                         DEFAULT)
    return seqs, seg, comp, office, office_seeds


def _detection_rate(rows, lo: float, thr: float, key: str = "iou", sel=None) -> tuple[int, float]:
    """(people covering at least ``lo`` of the image among ``rows`` (and ``sel``), the share of them detected: IoU
    ``key`` at least ``thr``)."""
    a, v = column(rows, "area"), column(rows, key)
    keep = (a >= lo) & (np.ones(len(a), bool) if sel is None else sel)
    return int(keep.sum()), (float((v[keep] >= thr).mean()) if keep.any() else float("nan"))


def _print_people_in_view(seqs, comp, office) -> None:
    print("  people in view (composites, every frame): frames with somebody covering >= 3 % of the image; the "
          "people's image share per frame with anybody, p10/p50/p90; each visible person's median depth (m), "
          "p10/p50/p90")
    for q in seqs:
        c = composite_coverage(q)
        print(f"    {q.root.name:<22} {100 * c['in_view']:5.1f} % of {c['frames']} frames; share "
              f"{'/'.join(f'{v:.3f}' for v in c['share'])}; depth {'/'.join(f'{v:.2f}' for v in c['depth'])}")
    print("  each visible person of the segmented frames: image share p10/p50/p90, median depth (m) p10/p50/p90")
    for name, rows in (("composites", comp), ("synthetic office", office)):
        a, z = column(rows, "area"), column(rows, "depth")
        print(f"    {name:<22} {'/'.join(f'{v:.3f}' for v in np.percentile(a, (10, 50, 90)))}; "
              f"{'/'.join(f'{v:.2f}' for v in np.nanpercentile(z, (10, 50, 90)))} ({len(rows)} people)")


def _print_detection(seqs, comp, office, lo: float, thr: float, target: float) -> str:
    """The detection rates as recorded, upright and isolated, per composite, over all and on the office; the
    verdict of all the composites against ``target``."""
    print("  detection rate of the people: as recorded, upright (the camera's roll undone), isolated (upright, the "
          "background grey)")
    print(f"  {'':<24} {'people':>6} {'detected':>9} {'upright':>9} {'isolated':>9}")
    verdict = ""
    for name, rows in [(q.root.name, [r for r in comp if r["sequence"] == q.root.name]) for q in seqs] + \
            [("all composites", comp), ("synthetic office", office)]:
        n, r0 = _detection_rate(rows, lo, thr)
        _, r1 = _detection_rate(rows, lo, thr, "iou_upright")
        _, r2 = _detection_rate(rows, lo, thr, "iou_isolated")
        print(f"  {name:<24} {n:>6} {r0:9.3f} {r1:9.3f} {r2:9.3f}")
        if name == "all composites":
            verdict = (f"detection >= {target:g}: {r0:.3f} {'met' if r0 >= target else 'NOT met'}"
                       f" (upright {r1:.3f} {'met' if r1 >= target else 'NOT met'})")
    return verdict


def _print_by_roll(comp, office, lo: float, thr: float) -> None:
    print("  detection rate by the camera's |roll| (deg), composites / office [people]:")
    edges = (0.0,) + ROLL_BINS + (np.inf,)
    cr, orr = np.abs(column(comp, "roll")), np.abs(column(office, "roll"))
    for a, b in zip(edges[:-1], edges[1:]):
        nc, rc = _detection_rate(comp, lo, thr, sel=(cr >= a) & (cr < b))
        no, ro = _detection_rate(office, lo, thr, sel=(orr >= a) & (orr < b))
        label = f"{a:.0f}-{b:.0f}" if np.isfinite(b) else f">= {a:.0f}"
        print(f"    {label:<8} {rc:6.3f} [{nc:>4}]  {ro:6.3f} [{no:>4}]")


def _print_iou_by_depth(comp, office, lo: float, bins) -> bool:
    """The mean IoU by depth bin, composites against the office; whether every bin both fill is within
    ``COMPOSITE_IOU_TOLERANCE`` as recorded."""
    print("  mean IoU by the person's median depth (people >= the area threshold): composites, office, difference")
    ok_all = True
    for key, what in (("iou", "as recorded"), ("iou_upright", "upright"), ("iou_isolated", "isolated")):
        big_c, big_o = column(comp, "area") >= lo, column(office, "area") >= lo
        tc = depth_bin_table(column(comp, "depth")[big_c], column(comp, key)[big_c], bins)
        to = depth_bin_table(column(office, "depth")[big_o], column(office, key)[big_o], bins)
        print(f"    {what}:")
        for (label, nc, mc, _), (_, no, mo, _) in zip(tc, to):
            d = mc - mo
            within = not (np.isfinite(d) and abs(d) > COMPOSITE_IOU_TOLERANCE)
            if key == "iou" and nc and no:
                ok_all &= within
            print(f"      {label:<12} {mc:6.3f} [{nc:>4}]  {mo:6.3f} [{no:>4}]  {d:+6.3f}"
                  + ("" if not (nc and no) else ("" if within else "  (beyond 0.1)")))
    return ok_all
