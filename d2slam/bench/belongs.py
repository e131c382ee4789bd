"""``d2slam bench belongs [RESULTS]``: how ``d2slam eval``'s residual rule (:mod:`d2slam.eval.belongs`, used when
neither the trajectory's header nor the ground truth's folder can tell) treats a study's runs: each run against its
own sequence's ground truth (refusals there are runs that failed while staying compact) and against every other
sequence's ground truth of the same length (synthetic sequences share a clock; refusals there are caught mistakes).
Reads ``RESULTS/runs/*.npz`` (matched ground-truth and estimated positions of every run)."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
from evo.core.geometry import umeyama_alignment

from d2slam.errors import D2SlamError
from d2slam.eval.belongs import residual_check

DESCRIPTION = "eval's residual rule on a study's runs: refused against their own ground truth and against the others'"


def add_arguments(parser) -> None:
    parser.add_argument("results", nargs="?", default="results", help="study folder (default: results)")


def run(args) -> int:

    files = sorted(Path(args.results).glob("runs/*.npz"))
    if not files:
        raise D2SlamError("no runs/*.npz: not a study folder", path=args.results)
    runs = []
    for f in files:
        m = re.match(r"(.*?)(_twin)?_s(\d+)_n(\d+)_(.*)", f.stem)
        with np.load(f) as d:
            runs.append(((m.group(1), int(m.group(3))), f.stem, d["est_xyz"], d["gt_xyz"]))
    truths = {seq: gt for seq, _, _, gt in runs}

    def refused(est, gt) -> bool:
        R, t, _ = umeyama_alignment(est.T, gt.T, False)
        return residual_check(gt, est @ R.T + t)[0]

    own = [name for seq, name, est, gt in runs if refused(est, gt)]
    others = [(est, gt) for seq, _, est, _ in runs for other, gt in truths.items()
              if other != seq and len(gt) == len(est)]
    caught = sum(refused(est, gt) for est, gt in others)
    print(f"{len(runs)} runs of {len(truths)} sequences in {args.results}")
    print(f"  against their own ground truth: {len(own)} refused" + (f" ({', '.join(own)})" if own else ""))
    share = 100 * caught / max(1, len(others))
    print(f"  against another sequence's: {caught} of {len(others)} refused ({share:.0f} %)")
    return 0
