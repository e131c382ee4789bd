"""Registry of run methods (``d2slam run --method NAME``): a name -> factory building the engine's keypoint filter.

``none`` is the engine with the hook off (our in-engine stand-in for ORB-SLAM3). The dynamics methods (``d2slam``,
``no-depth``, ``no-oim``, ``no-bayes``, ``semantic``, ``geometric``), the real ``orbslam3`` baseline and
``orbslam3-masked`` (the real ORB-SLAM3 on frames with the people's pixels removed) plug in here
with :func:`register` (one line each; the dynamics methods are the classifier with its switches, :data:`DYNAMICS`)::

    register("no-oim", _Dynamics("no-oim", switches=Switches(oim=False)), needs_masks=True)

A factory returns an object with ``__call__(FilterInput) -> (N,) beliefs`` and ``reset()``, or None (hook off).
``oracle`` (the keypoint truth as the filter: the upper bound of every method) always runs on the ``truth`` masks
(``Method.masks``), so it exists for synthetic sequences only.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Callable

from d2slam.config import Config
from d2slam.dynamics.switches import Switches
from d2slam.errors import D2SlamError

if TYPE_CHECKING:  # the records' module loads numpy and the data readers: not for listing the methods
    from d2slam.record import RunRecord


@dataclass(frozen=True)
class Method:
    name: str
    factory: Callable[[Config], object | None]
    needs_masks: bool = False
    help: str = ""
    # A method that is not a keypoint filter of our engine (the real ORB-SLAM3): ``runner(args) -> RunRecord`` runs
    # it for ``d2slam run`` (its arguments; it writes --out and --metrics-json itself) instead of the engine
    # (``factory`` is then unused and returns None).
    runner: Callable[[object], RunRecord] | None = None
    # The mask kind the method always uses (``--masks`` cannot change it), or None: the run's choice.
    masks: str | None = None


_REGISTRY: dict[str, Method] = {}
# The masks of a method that needs some when none are asked for: the real segmenter, everywhere.
DEFAULT_MASKS = "onnx"


def register(name: str, factory: Callable[[Config], object | None], needs_masks: bool = False,
             help: str = "", runner: Callable[[object], RunRecord] | None = None, masks: str | None = None) -> None:
    _REGISTRY[name] = Method(name, factory, needs_masks, help, runner, masks)


def mask_kind(method: Method, requested: str | None, synthetic: bool) -> str | None:
    """The masks a run of ``method`` reads: the method's own kind, else ``requested`` (``--masks``), else the real
    segmenter's (``onnx``, on synthetic sequences too, as the study's) when the method needs masks (None: no masks).
    ``synthetic``: whether the sequence has the truth a method with its own ``truth``/``sim`` masks needs."""
    if method.masks is not None:
        if requested not in (None, method.masks):
            raise D2SlamError(f"--method {method.name} always uses the '{method.masks}' masks, not {requested!r}")
        if not synthetic:
            raise D2SlamError(f"--method {method.name} needs the '{method.masks}' masks of a synthetic sequence "
                              "(made by `d2slam synth`); real data has no such truth")
        return method.masks
    if requested is None and method.needs_masks:
        return DEFAULT_MASKS
    return requested


def run_method(seq, name: str, config: Config, masks: str | None = None, mask_seq=None, synthetic: bool = False,
               features: Callable[[object], object] | None = None, progress: bool | None = None,
               desc: str | None = None, frames: int | None = None) -> RunRecord:
    """Run method ``name`` of our engine on ``seq`` (its first ``frames`` frames when given): its keypoint filter,
    the masks :func:`mask_kind` picks from ``masks`` (read from ``mask_seq`` when given: the same frames of another
    sequence), the keypoint truth recorded on synthetic sequences, the trajectory and loops evaluated against the
    ground truth. ``features(keypoint_filter)`` may return stored features for ``run_sequence``. The one place
    where ``d2slam run`` and the study run a method; the real ORB-SLAM3 (``runner``) is not run here."""
    from d2slam.eval.keypoints import keypoint_recorder
    from d2slam.eval.loops import loop_summary
    from d2slam.eval.trajectory import evaluate_run
    from d2slam.pipeline import run_sequence
    from d2slam.record import RunRecord

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
    return RunRecord(method=name, sequence=getattr(seq, "name", ""), trajectory=run.trajectory, frames=run.frames,
                     tracked=run.tracked, lost=run.lost, fps=run.fps, ms_per_frame=run.ms_per_frame,
                     config_hash=config.hash(), loop_closing=run.loop_closing, status=status, error=error,
                     evaluation=evaluation, stage_ms=run.stage_ms, masks=kind, masks_origin=origin,
                     keypoints=recorder.result() if recorder is not None else None,
                     loops=loop_summary(run, seq.timestamps, gt, config.evaluation), keyframes=run.keyframes,
                     map_points=run.map_points, engine=run,
                     min_tracked_share=config.evaluation.min_tracked_share)


def _mask_provider(seq, kind: str, mask_seq, config: Config, frames: int, progress: bool | None):
    """``provider(i)`` of the ``kind`` person masks of frame ``i`` (of ``mask_seq`` when given) as an (n, H, W)
    stack, and where they come from; the real segmenter's masks missing from the cache are computed now,
    announced, before the run."""
    from d2slam.segmentation import mask_source, masks_for, masks_origin, stack_masks

    shape = (seq.camera.height, seq.camera.width)
    src = seq if mask_seq is None else mask_source(seq, mask_seq)
    origin = masks_origin(src, kind, config, frames=frames, progress=progress is not False)
    if mask_seq is not None and kind == "onnx":  # the label kinds name their folder already
        origin = f"{origin}, of {Path(mask_seq.root).resolve()}"

    def provider(i):
        return stack_masks(masks_for(src, i, kind, config), shape)

    return provider, origin


def methods() -> list[str]:
    return list(_REGISTRY)


def get_method(name: str) -> Method:
    if name not in _REGISTRY:
        raise D2SlamError(f"unknown method {name!r}; choose one of {', '.join(_REGISTRY)}")
    return _REGISTRY[name]


def get_filter(name: str, config: Config | None = None):
    """The keypoint filter of method ``name`` (None for ``none``); ``config``: a ``Config`` or, for the dynamics
    methods, a ``DynamicsConfig`` (default: the defaults)."""
    return get_method(name).factory(config)


register("none", lambda config: None, needs_masks=False, help="engine with the keypoint filter off (ORB-SLAM3 "
         "stand-in)")



def _orbslam3_runner(args) -> RunRecord:
    """``d2slam run --method orbslam3[-masked]``: the real ORB-SLAM3 on ``args.sequence`` (on frames with the people
    removed when ``args.masks`` is set), writing ``args.out`` and ``args.metrics_json``."""
    from d2slam.baselines.orbslam3 import run_orbslam3  # imported on use: pyorbslam3 loads only for this method

    return run_orbslam3(args.sequence, args.out, getattr(args, "metrics_json", None),
                        repeats=getattr(args, "repeats", 1) or 1, vocab=getattr(args, "vocab", None),
                        camera=getattr(args, "camera", None),
                        progress=not getattr(args, "quiet", False), masks=getattr(args, "masks", None),
                        online_rate=(getattr(args, "rate", None) or 0.0) if getattr(args, "online", False) else None)


register("orbslam3", lambda config: None, needs_masks=False, runner=_orbslam3_runner,
         help="the real ORB-SLAM3 RGB-D (pyorbslam3) on the sequence, not our engine: d2slam.baselines.orbslam3")


def _orbslam3_masked_runner(args) -> RunRecord:
    from d2slam.data import SyntheticSequence, open_sequence

    seq = open_sequence(args.sequence, **({"camera": args.camera} if getattr(args, "camera", None) else {}))
    args.masks = mask_kind(get_method("orbslam3-masked"), args.masks, synthetic=isinstance(seq, SyntheticSequence))
    return _orbslam3_runner(args)


register("orbslam3-masked", lambda config: None, needs_masks=True, runner=_orbslam3_masked_runner,
         help="the real ORB-SLAM3 RGB-D on frames whose person pixels (--masks) are removed: depth 0, RGB filled "
              "(d2slam.baselines.masking)")


def _oracle(config: Config):
    from d2slam.eval.keypoints import OracleFilter

    return OracleFilter()


register("oracle", _oracle, needs_masks=True, masks="truth",
         help="upper bound, not a method: the keypoint truth (persons, moved objects while they move) as the filter; "
              "synthetic sequences only")

class _Dynamics:
    """config -> a filter of ``d2slam.dynamics.classifier`` (``kind``: its class name; ``switches`` for
    ``D2SlamFilter``), imported when a filter is built: the command line lists the methods without loading it."""

    def __init__(self, name: str, kind: str = "D2SlamFilter", switches: Switches | None = None):
        self.name, self.kind, self.switches = name, kind, switches

    def __call__(self, config=None):
        from d2slam.dynamics import classifier

        cls = getattr(classifier, self.kind)
        if self.switches is None:
            return cls(config, name=self.name)
        return cls(config, self.switches, name=self.name)

    def __repr__(self) -> str:
        return f"dynamics filter factory {self.name!r}"


# The paper's method and its ablations (the classifier with one switch off), and the two single-module baselines:
# name -> (factory, needs masks, ``d2slam run --help`` text).
DYNAMICS = {
    "d2slam": (_Dynamics("d2slam", switches=Switches()), True,
               "full D2SLAM: semantic + geometric + Bayesian fusion + object interaction (eq 1-10)"),
    "d2slam-flow": (_Dynamics("d2slam-flow", switches=Switches(flow=True)), True,
                    "ours: d2slam with sub-pixel LK flow correspondences for eq 5 and the edge band "
                    "(DynamicsConfig.flow, flow_edge_band)"),
    "no-depth": (_Dynamics("no-depth", switches=Switches(depth=False)), True,
                 "D2SLAM with every depth-adaptive quantity at its midpoint and no OIM depth test"),
    "no-oim": (_Dynamics("no-oim", switches=Switches(oim=False)), True,
               "D2SLAM without the object interaction module (eq 9-10)"),
    "no-bayes": (_Dynamics("no-bayes", switches=Switches(bayes=False)), True,
                 "D2SLAM with the eq 7 probability used directly (no eq 8 filter)"),
    "semantic": (_Dynamics("semantic", "SemanticFilter"), True,
                 "masks only, DynaSLAM-like: keypoints inside a person mask are dynamic"),
    "geometric": (_Dynamics("geometric", "EpipolarFilter"), False,
                  "epipolar check only (fixed threshold), no masks, no filter"),
}
FILTER_HELP = {name: text for name, (_, _, text) in DYNAMICS.items()}
for _name, (_factory, _needs_masks, _help) in DYNAMICS.items():
    register(_name, _factory, needs_masks=_needs_masks, help=_help)


def _d2slam(config: Config):
    return get_method("d2slam").factory(config)


register("d2slam-sim", _d2slam, needs_masks=True, masks="sim",
         help="d2slam on the simulated segmenter's masks (mask_sim of a synthetic sequence) instead of the real one's")
