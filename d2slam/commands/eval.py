"""``d2slam eval GROUNDTRUTH TRAJ.txt``: ATE / RPE with evo (TUM conventions)."""

from __future__ import annotations

import json
from pathlib import Path

from d2slam.data import read_tum_trajectory
from d2slam.errors import D2SlamError
from d2slam.eval.belongs import check_belongs, header_lines
from d2slam.eval.plots import plot_trajectory
from d2slam.eval.trajectory import evaluate
from d2slam.outputs import check_output_file, check_outputs


def register(sub) -> None:
    p = sub.add_parser(
        "eval", help="ATE and RPE of a trajectory against ground truth (evo)",
        description="ATE RMSE after SE(3) Umeyama alignment (0.02 s association) and RPE translational (m) and "
        "rotational (deg) RMSE over all 1-second pairs, computed with evo. GROUNDTRUTH is a TUM trajectory file "
        "or a sequence folder holding groundtruth.txt. A trajectory that does not belong to the ground truth is "
        "refused (another synthetic sequence named in its header, timestamps that are not the folder's frame times, "
        "or against a bare file an ATE far beyond the ground truth's extent) unless --force is given.")
    p.add_argument("groundtruth", metavar="GROUNDTRUTH")
    p.add_argument("trajectory", metavar="TRAJ.txt")
    p.add_argument("--force", action="store_true", help="evaluate even a trajectory that does not seem to belong to "
                   "the ground truth")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--plot", metavar="PNG", help="save a trajectory plot against ground truth")
    p.set_defaults(func=run)


def run(args) -> int:
    if args.plot:
        check_output_file(args.plot, "--plot")
        check_outputs([("--plot", args.plot)], [("ground truth", args.groundtruth), ("trajectory", args.trajectory)])
    gt_path, gt_folder = ground_truth_file(Path(args.groundtruth), Path(args.trajectory))
    gt = read_tum_trajectory(gt_path)
    est = read_tum_trajectory(args.trajectory)
    gt.meta["path"], est.meta["path"] = str(gt_path), str(args.trajectory)
    m = evaluate(gt, est).to_dict()
    if not args.force:
        check_belongs(gt, est, gt_path, gt_folder, Path(args.trajectory))
    if args.plot:
        plot_trajectory(gt, est, args.plot, title=Path(args.trajectory).name, metrics=m)
    if args.json:
        print(json.dumps(m))
    else:
        print(f"ate_rmse_m {m['ate_rmse_m']:.6f}\nrpe_trans_m {m['rpe_trans_m']:.6f}\n"
              f"rpe_rot_deg {m['rpe_rot_deg']:.6f}\nmatched {m['n_matched']}/{m['n_estimated']} poses, "
              f"{m['n_rpe_pairs']} RPE pairs")
    return 0


def ground_truth_file(gt, traj) -> tuple:
    """(ground-truth file, its sequence folder or None) from the two arguments, with a one-line error saying what is
    wrong when they are missing, of the wrong kind, or given in the wrong order."""
    order = "the order is `d2slam eval GROUNDTRUTH TRAJ.txt`"
    if not gt.exists():
        raise D2SlamError("ground truth not found (a TUM trajectory file or a sequence folder)", path=gt)
    if not traj.exists():
        raise D2SlamError("trajectory file not found", path=traj)
    if traj.is_dir():
        swapped = gt.is_file() and (traj / "groundtruth.txt").is_file()
        raise D2SlamError("TRAJ.txt is a folder, not a trajectory file" + (
            f": the arguments look swapped ({order})" if swapped else f" ({order})"), path=traj)
    if gt.is_dir():
        if not (gt / "groundtruth.txt").is_file():
            raise D2SlamError("no groundtruth.txt in this folder" + (": the sequence has no ground truth" if
                              (gt / "rgb.txt").is_file() else f" (GROUNDTRUTH: a TUM trajectory file or a sequence "
                              f"folder; {order})"), path=gt)
        return gt / "groundtruth.txt", gt
    run_made = any(line.lstrip("# ").startswith(("d2slam run", "d2slam orbslam3")) for line in header_lines(gt))
    if run_made and any("ground truth" in line for line in header_lines(traj)):
        raise D2SlamError(f"GROUNDTRUTH was written by d2slam and TRAJ.txt is a ground truth: the arguments look "
                          f"swapped ({order})", path=gt)
    return gt, None
