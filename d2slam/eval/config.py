"""How a run is judged (``EvalConfig``)."""

from __future__ import annotations

from dataclasses import dataclass

from d2slam.ranges import Checked, within


@dataclass(frozen=True)
class EvalConfig(Checked):
    """How a run is judged: the share of its frames it tracked (``d2slam.run.record``) and its loops against the ground
    truth (``d2slam.eval.loops``); nothing here changes a trajectory."""

    # A run that tracks less than this share of the frames it ran is a fragment, not a result: its ATE and RPE are
    # over the tracked frames only (the TUM convention), so a run lost after a few frames can show a smaller error
    # than one that tracked them all. `d2slam run` says so in its summary line and run JSON and exits with status 3;
    # the study's runs.csv records it (fragment) and its tables mark the cells whose median share is below it.
    min_tracked_share: float = within(0.9, 0.0, 1.0)

    # A detected loop is true when the relative pose of its two keyframes that the loop closer estimated is within
    # both of these of the ground truth's relative pose, false otherwise.
    loop_true_max_m: float = within(0.10, 0.0, 100.0, lo_open=True)
    loop_true_max_deg: float = within(5.0, 0.0, 180.0, lo_open=True)
    # A place-recognition candidate is wrong (it shows another place) when the two ground-truth views do not overlap:
    # optical axes more than loop_wrong_view_deg apart or camera centres more than loop_wrong_view_m apart.
    loop_wrong_view_deg: float = within(60.0, 0.0, 180.0)
    loop_wrong_view_m: float = within(1.5, 0.0, 100.0)


@dataclass(frozen=True)
class BelongsConfig(Checked):
    """Whether a trajectory belongs to a ground truth (``d2slam eval``, :mod:`d2slam.eval.belongs`); nothing here
    changes a run's numbers (a section of ``d2slam.config.CliConfig``, not of ``Config``)."""

    # `d2slam eval GROUNDTRUTH TRAJ` (d2slam.eval.belongs): a trajectory belongs to a sequence folder when at least
    # eval_min_frame_share of its timestamps are the folder's frame times (rgb.txt or depth.txt, within
    # eval_frame_tolerance_s; synthetic sequences share a clock but each (scenario, seed) has its own frame jitter of
    # up to 1.5 ms); a bare ground-truth file when it holds the positions of the groundtruth.txt of the sequence the
    # trajectory's header names (within eval_same_gt_m). With neither, a trajectory whose ATE RMSE exceeds
    # eval_ate_floor_m and eval_ate_extent_ratio x the ground truth's extent (RMS distance of its matched positions
    # from their centroid), while its own extent is at most eval_est_extent_max x that, is refused (--force).
    eval_frame_tolerance_s: float = within(1e-4, 0.0, 10.0, lo_open=True)
    eval_min_frame_share: float = within(0.5, 0.0, 1.0)
    eval_same_gt_m: float = within(1e-3, 0.0, 100.0, lo_open=True)
    eval_ate_floor_m: float = within(0.05, 0.0, 1000.0)
    eval_ate_extent_ratio: float = within(0.5, 0.0, 1000.0)
    eval_est_extent_max: float = within(1.5, 0.0, 1000.0)
