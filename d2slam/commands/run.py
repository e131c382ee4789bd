"""``d2slam run SEQUENCE_DIR --method none --out TRAJ.txt``: run the SLAM engine on a sequence."""

from __future__ import annotations


def register(sub) -> None:
    from d2slam.methods import methods

    p = sub.add_parser(
        "run", help="run the SLAM engine on a TUM or synthetic sequence",
        description="Run the ORB-SLAM3-style RGB-D engine on SEQUENCE_DIR (TUM layout, or a d2slam synthetic "
        "sequence) with a keypoint-filter method, write the trajectory of the tracked frames in TUM format and, "
        "with --metrics-json, frames/tracked/lost/fps, mean milliseconds per stage, the config hash and (when the "
        "sequence has ground truth) ATE/RPE computed with evo.")
    p.add_argument("sequence", metavar="SEQUENCE_DIR")
    p.add_argument("--method", default="none", choices=methods(), help="keypoint filter (default: none)")
    p.add_argument("--out", required=True, metavar="TRAJ.txt", help="estimated trajectory (TUM format)")
    p.add_argument("--metrics-json", metavar="RUN.json", help="write run statistics and metrics as JSON")
    p.add_argument("--masks", choices=["gt", "sim", "onnx", "truth"], default=None,
                   help="person masks given to the filter (default: sim on synthetic sequences, onnx otherwise, "
                   "when the method needs masks; never computed for --method none unless asked). truth: the "
                   "synthetic dynamic truth (persons and moving objects), what --method oracle always uses")
    p.add_argument("--masks-from", metavar="SEQUENCE_DIR", default=None,
                   help="read the masks from this sequence instead (same frames and timestamps), e.g. --method "
                   "oracle on a static twin with its dynamic sequence: the occluded twin of the study")
    p.add_argument("--camera", metavar="fr1|fr2|fr3", default=None,
                   help="camera of a TUM folder whose name does not say (synthetic sequences carry their own)")
    p.add_argument("--seed", type=int, default=0, help="seed of the engine's RANSAC (relocalisation)")
    p.add_argument("--repeats", type=int, default=1, help="--method orbslam3 and orbslam3-masked only: runs of "
                   "ORB-SLAM3 (default 1)")
    p.add_argument("--quiet", action="store_true", help="no progress bar, no summary")
    p.set_defaults(func=run)


def run(args) -> int:
    import dataclasses
    import json
    from pathlib import Path

    from d2slam.config import DEFAULT
    from d2slam.data import SyntheticSequence, open_sequence, write_tum_trajectory
    from d2slam.errors import D2SlamError
    from d2slam.eval.keypoints import keypoint_recorder
    from d2slam.methods import get_method, mask_kind
    from d2slam.pipeline import run_sequence

    method = get_method(args.method)
    if method.runner is not None:  # not a keypoint filter of our engine (orbslam3[-masked]): its own command
        if args.masks_from is not None:
            raise D2SlamError(f"--masks-from does not apply to --method {args.method}")
        if args.masks is not None and not method.needs_masks:
            raise D2SlamError(f"--masks does not apply to --method {args.method}")
        return method.runner(args)

    out = Path(args.out)
    if not out.parent.is_dir():
        raise D2SlamError("output folder does not exist", path=out.parent)
    config = dataclasses.replace(DEFAULT, engine=dataclasses.replace(DEFAULT.engine, ransac_seed=args.seed))
    seq = open_sequence(args.sequence, **({"camera": args.camera} if args.camera else {}))
    kfilter = method.factory(config)
    masks_kind = mask_kind(method, args.masks, synthetic=isinstance(seq, SyntheticSequence))
    provider = None
    if args.masks_from is not None and masks_kind is None:
        raise D2SlamError(f"--masks-from: --method {args.method} reads no masks")
    if masks_kind is not None:
        from d2slam.segmentation import mask_source, masks_for, stack_masks

        shape = (seq.camera.height, seq.camera.width)
        src = seq if args.masks_from is None else mask_source(seq, open_sequence(args.masks_from))

        def provider(i):
            return stack_masks(masks_for(src, i, masks_kind, config), shape)

    rec = keypoint_recorder(seq)  # keypoint truth (synthetic sequences only; None on TUM folders)
    result = run_sequence(seq, config, keypoint_filter=kfilter, mask_provider=provider, recorder=rec,
                          progress=False if args.quiet else None, desc=f"{args.method} {seq.name}")
    if result.tracked == 0:
        write_tum_trajectory(out, result.trajectory, header=f"d2slam run {args.method}: no frame tracked")
    else:
        write_tum_trajectory(out, result.trajectory, header=f"d2slam run --method {args.method} {seq.root}")
    record = {"sequence": str(seq.root), "name": seq.name, "method": args.method, "masks": masks_kind,
              **({"masks_from": str(src.root)} if args.masks_from is not None else {}),
              "seed": args.seed, "config_hash": config.hash(), **result.summary(),
              "trajectory": str(out)}
    if rec is not None:
        record["keypoints"] = rec.result()
    gt = seq.groundtruth
    if gt is not None and result.tracked >= 3:
        from d2slam.eval.trajectory import evaluate

        try:
            record["metrics"] = evaluate(gt, result.trajectory).to_dict()
        except D2SlamError as exc:
            record["metrics_error"] = str(exc)
    for k in ("load", "extract", "filter", "track", "local_ba", "segment"):
        if k in result.stage_ms:
            record[f"{k}_ms"] = round(result.stage_ms[k], 3)
    if args.metrics_json:
        Path(args.metrics_json).write_text(json.dumps(record, indent=2) + "\n")
    if not args.quiet:
        print(f"{seq.name}: {result.frames} frames, {result.tracked} tracked, {result.lost} lost, "
              f"{result.keyframes} keyframes, {result.fps:.1f} fps")
        print("ms/frame: " + ", ".join(f"{k} {v:.1f}" for k, v in result.stage_ms.items()))
        if "metrics" in record:
            m = record["metrics"]
            print(f"ate_rmse_m {m['ate_rmse_m']:.4f}  rpe_trans_m {m['rpe_trans_m']:.4f}  "
                  f"rpe_rot_deg {m['rpe_rot_deg']:.3f}")
    return 0
