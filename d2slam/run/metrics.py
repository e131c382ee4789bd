"""The run JSON of ``d2slam run --metrics-json`` for the engine's methods, made from the run's
:class:`~d2slam.run.record.RunRecord` in one place (:func:`run_json`); the real ORB-SLAM3 writes its own
(``d2slam.baselines.orbslam3``)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path

from d2slam.config import Config
from d2slam.eval.fragment import fragment_fields
from d2slam.run.record import RunRecord
from d2slam.run.sequence import STAGES


@dataclass
class RunSource:
    """What a run was made of, beside its record: the sequence, the run's seed, where the camera came from (a
    settings file, ``scene.json``, the folder name or ``--camera NAME``), the trajectory file written, the sequence
    the masks were read from (``--masks-from``), the config file with its overrides and the config they made, and the
    vocabulary loop closing loaded (``{"path", "sha256"}``)."""

    seq: object
    seed: int
    camera_source: str
    trajectory: Path
    mask_seq: object | None = None
    config_file: Path | None = None
    overrides: dict | None = None
    config: Config | None = None
    vocabulary: dict | None = None


def run_json(record: RunRecord, src: RunSource, startup_s: float) -> dict:
    """The run JSON: the run's inputs, the engine's figures, the keypoints against the truth, the loops, ATE / RPE
    (or why there are none), the share tracked (a fragment says so), the milliseconds per stage and ``startup_s``
    (the process start to the end of the first frame)."""
    seq, engine = src.seq, record.engine
    out = {"sequence": str(seq.root), "name": seq.name, "method": record.method, "masks": record.masks,
           **({"masks_from": str(src.mask_seq.root)} if src.mask_seq is not None else {}),
           **({"masks_origin": record.masks_origin} if record.masks_origin else {}),
           "seed": src.seed, "config_hash": record.config_hash,
           "camera": {**dataclasses.asdict(seq.camera), "source": src.camera_source},
           **({"config_file": str(Path(src.config_file).resolve()), "config_overrides": src.overrides,
               "config": src.config.to_dict()} if src.config_file else {}),
           **engine.summary(), "trajectory": str(src.trajectory)}
    if record.keypoints is not None:
        out["keypoints"] = record.keypoints
    out.update(record.loops)
    if src.vocabulary is not None:
        out["vocabulary"] = src.vocabulary
    out.update(metrics_fields(record))
    listed = getattr(seq, "n_rgb", record.frames)
    if record.frames < listed:
        out["frames_note"] = (f"{record.frames} of the {listed} frames of rgb.txt were run: the others have no "
                              f"depth image within {seq.max_dt:g} s (depth.txt lists {seq.n_depth})")
    out.update(fragment_fields(record.tracked, record.frames, record.min_tracked_share))
    for k in STAGES:
        if k in record.stage_ms:
            out[f"{k}_ms"] = round(record.stage_ms[k], 3)
    out["startup_s"] = round(startup_s, 3)
    return out


def metrics_fields(record: RunRecord) -> dict:
    """``metrics`` (ATE and RPE, or the ATE alone) and ``metrics_error`` (why some or all are missing)."""
    ev = record.evaluation
    if ev is None:
        return {"metrics_error": "no ATE/RPE: the sequence has no groundtruth.txt"}
    if record.tracked < 3:
        return {"metrics_error": f"no ATE/RPE: only {record.tracked} frames tracked (at least 3 are needed)"}
    if ev.metrics is not None:
        return {"metrics": ev.metrics.to_dict()}
    if ev.ate_rmse_m is not None:  # too short for 1-second pairs: the ATE alone
        return {"metrics": {"ate_rmse_m": ev.ate_rmse_m}, "metrics_error": f"no RPE: {ev.error}"}
    return {"metrics_error": f"no ATE/RPE: {ev.error}"}
