"""``d2slam eval GROUNDTRUTH TRAJ.txt``: ATE / RPE with evo (TUM conventions)."""

from __future__ import annotations


def register(sub) -> None:
    p = sub.add_parser(
        "eval", help="ATE and RPE of a trajectory against ground truth (evo)",
        description="ATE RMSE after SE(3) Umeyama alignment (0.02 s association) and RPE translational (m) and "
        "rotational (deg) RMSE over all 1-second pairs, computed with evo. GROUNDTRUTH is a TUM trajectory file "
        "or a sequence folder holding groundtruth.txt.")
    p.add_argument("groundtruth", metavar="GROUNDTRUTH")
    p.add_argument("trajectory", metavar="TRAJ.txt")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--plot", metavar="PNG", help="save a trajectory plot against ground truth")
    p.set_defaults(func=run)


def run(args) -> int:
    import json
    from pathlib import Path

    from d2slam.data import read_tum_trajectory
    from d2slam.errors import D2SlamError
    from d2slam.eval.trajectory import evaluate

    from d2slam.outputs import check_output_file

    if args.plot:
        check_output_file(args.plot, "--plot")
    gt_path = Path(args.groundtruth)
    if gt_path.is_dir():
        gt_path = gt_path / "groundtruth.txt"
    for p in (gt_path, Path(args.trajectory)):
        if not p.is_file():
            raise D2SlamError("file not found", path=p)
    gt = read_tum_trajectory(gt_path)
    est = read_tum_trajectory(args.trajectory)
    gt.meta["path"], est.meta["path"] = str(gt_path), str(args.trajectory)
    m = evaluate(gt, est).to_dict()
    if args.plot:
        from d2slam.eval.plots import plot_trajectory

        plot_trajectory(gt, est, args.plot, title=Path(args.trajectory).name, metrics=m)
    if args.json:
        print(json.dumps(m))
    else:
        print(f"ate_rmse_m {m['ate_rmse_m']:.6f}\nrpe_trans_m {m['rpe_trans_m']:.6f}\n"
              f"rpe_rot_deg {m['rpe_rot_deg']:.6f}\nmatched {m['n_matched']}/{m['n_estimated']} poses, "
              f"{m['n_rpe_pairs']} RPE pairs")
    return 0
