"""One run of a method of our engine on a sequence (:func:`run_method`): its keypoint filter (from the registry,
:mod:`d2slam.run.methods`), its masks, the loop over the frames (:func:`d2slam.run.sequence.run_sequence`) and the
record (:class:`~d2slam.run.record.RunRecord`) evaluated against the ground truth. The one place where ``d2slam run``
and the study run a method; the real ORB-SLAM3 has its own runner (:mod:`d2slam.run.orbslam3_runs`)."""

from __future__ import annotations

from pathlib import Path
from typing import Callable

from d2slam.config import Config
from d2slam.errors import D2SlamError
from d2slam.eval.keypoints import keypoint_recorder
from d2slam.eval.loops import loop_summary
from d2slam.eval.trajectory import evaluate_run
from d2slam.ranges import overridden
from d2slam.run.methods import get_method, mask_kind
from d2slam.run.record import RunRecord
from d2slam.run.sequence import run_sequence
from d2slam.segmentation import mask_source, masks_for, masks_origin, stack_masks


def run_config(config: Config, seed: int = 0, loop_closing: bool = True, th_depth: float | None = None) -> Config:
    """``config`` as one run uses it: the run's seed (``EngineConfig.seed``: ``d2slam run --seed``, the study's
    seed), loop closing off when the run asks (``--no-loop-closing``; it stays off when the config turns it off), and a
    camera settings file's ThDepth when it has one (``--camera FILE``)."""
    engine = {"seed": int(seed), "loop_closing": bool(config.engine.loop_closing and loop_closing)}
    if th_depth is not None:
        engine["th_depth"] = th_depth
    return overridden(config, {"engine": engine})


def run_method(seq, name: str, config: Config, masks: str | None = None, mask_seq=None, synthetic: bool = False,
               features: Callable[[object], object] | None = None, progress: bool | None = None,
               desc: str | None = None, frames: int | None = None) -> RunRecord:
    """Run method ``name`` of our engine on ``seq`` (its first ``frames`` frames when given): its keypoint filter,
    the masks :func:`mask_kind` picks from ``masks`` (read from ``mask_seq`` when given: the same frames of another
    sequence), the keypoint truth recorded on synthetic sequences, the trajectory and loops evaluated against the
    ground truth. ``features(keypoint_filter)`` may return stored features for ``run_sequence``. The one place
    where ``d2slam run`` and the study run a method; the real ORB-SLAM3 (``runner``) is not run here."""
    method = get_method(name)
    if method.runner is not None:
        raise D2SlamError(f"--method {name} is not a keypoint filter of the engine: it has its own runner")
    kfilter = method.factory(config)
    kind = mask_kind(method, masks, synthetic=synthetic)
    if mask_seq is not None and kind is None:
        raise D2SlamError(f"--masks-from: --method {name} reads no masks")
    n = len(seq) if frames is None else min(len(seq), int(frames))
    provider, origin = _mask_provider(seq, kind, mask_seq, config, n, progress) if kind is not None else (None, None)
    recorder = keypoint_recorder(seq)
    run = run_sequence(seq, config, keypoint_filter=kfilter, mask_provider=provider, recorder=recorder,
                       progress=progress, desc=desc, features=features(kfilter) if features else None, frames=n)
    gt = seq.groundtruth
    evaluation = evaluate_run(gt, run.trajectory) if gt is not None else None
    status, error = ("unevaluated", "the sequence has no ground truth") if evaluation is None else \
        (evaluation.status, {"ok": "", "partial": f"ATE only: {evaluation.error}"}.get(
            evaluation.status, f"evaluation: {evaluation.error}"))
    return RunRecord(method=name, sequence=getattr(seq, "name", ""), run=run, config_hash=config.hash(),
                     status=status, error=error, evaluation=evaluation, masks=kind, masks_origin=origin,
                     keypoints=recorder.result() if recorder is not None else None,
                     loops=loop_summary(run, seq.timestamps, gt, config.evaluation),
                     min_tracked_share=config.evaluation.min_tracked_share)


def _mask_provider(seq, kind: str, mask_seq, config: Config, frames: int, progress: bool | None):
    """``provider(i)`` of the ``kind`` person masks of frame ``i`` (of ``mask_seq`` when given) as an (n, H, W)
    stack, and where they come from; the real segmenter's masks missing from the cache are computed now,
    announced, before the run."""
    shape = (seq.camera.height, seq.camera.width)
    src = seq if mask_seq is None else mask_source(seq, mask_seq)
    origin = masks_origin(src, kind, config, frames=frames, progress=progress is not False)
    if mask_seq is not None and kind == "onnx":  # the label kinds name their folder already
        origin = f"{origin}, of {Path(mask_seq.root).resolve()}"

    def provider(i):
        return stack_masks(masks_for(src, i, kind, config), shape)

    return provider, origin
