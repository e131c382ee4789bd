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
from typing import Callable

from d2slam.config import Config
from d2slam.data import SyntheticSequence, open_sequence
from d2slam.dynamics import classifier
from d2slam.dynamics.config import FLOW_FIELDS, OIM_FIELDS, fields_read
from d2slam.dynamics.switches import Switches
from d2slam.errors import D2SlamError
from d2slam.ranges import flat_fields
from d2slam.segmentation.config import NOT_IN_KEY
from d2slam.eval.keypoints import OracleFilter
from d2slam.run.orbslam3_runs import run_orbslam3
from d2slam.run.record import RunRecord


# What a run reads, by the kind of run: the config sections and the parts of the package (folders or files of
# d2slam/) whose source decides its numbers. The study keys a run by them (d2slam.study.keys), so that a change
# elsewhere does not re-run it.
RUN_CODE = ("run/__init__.py", "run/methods.py", "run/metrics.py", "run/observe.py", "run/record.py",
            "run/runner.py", "run/sequence.py", "run/warmup.py", "config.py", "ranges.py", "study/runner.py")
ENGINE_SECTIONS = ("orb", "engine", "data", "evaluation")
ENGINE_CODE = ("slam", "data", "eval") + RUN_CODE
# the classifier without the OIM's code and flow's (added for the methods that use them)
DYNAMICS_CODE = tuple(f"dynamics/{n}.py" for n in ("__init__", "classifier", "config", "depth", "fusion",
                                                    "geometric", "kernels", "semantic", "switches"))
OIM_CODE, FLOW_CODE = ("dynamics/interaction.py",), ("dynamics/flow.py",)
MASK_CODE = ("segmentation",)  # the real segmenter's masks (and its config, but what does not change them)
ORBSLAM3_SECTIONS = ("baseline", "data", "evaluation")
ORBSLAM3_CODE = ("baselines", "data", "eval", "run/orbslam3_runs.py", "run/record.py", "run/metrics.py",
                 "config.py", "ranges.py", "study/runner.py")


def sections_read(*names: str) -> Callable[[Config], dict]:
    """``reads`` of a method that reads whole config sections."""
    return lambda config: {n: flat_fields(getattr(config, n)) for n in names}


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
    # What a run of it reads: ``reads(config)`` -> {section: its fields read, as a dict}; ``code``: the parts of the
    # package whose source decides its numbers (with the masks' when it reads the real segmenter's, ``mask_code``).
    reads: Callable[[Config], dict] = sections_read(*ENGINE_SECTIONS)
    code: tuple[str, ...] = ENGINE_CODE


_REGISTRY: dict[str, Method] = {}
# The masks of a method that needs some when none are asked for: the real segmenter, everywhere.
DEFAULT_MASKS = "onnx"


def register(name: str, factory: Callable[[Config], object | None], needs_masks: bool = False,
             help: str = "", runner: Callable[[object], RunRecord] | None = None, masks: str | None = None,
             reads: Callable[[Config], dict] | None = None, code: tuple[str, ...] = ENGINE_CODE) -> None:
    _REGISTRY[name] = Method(name, factory, needs_masks, help, runner, masks,
                             reads or sections_read(*ENGINE_SECTIONS), code)


def run_reads(method: Method, config: Config, masks: str | None) -> tuple[dict, tuple[str, ...]]:
    """What a run of ``method`` with ``masks`` (its :func:`mask_kind`) reads: the config values and the package's
    source parts, the segmenter's included when the masks are the real segmenter's (``onnx``), the OIM's and the
    flow's when it reads their fields."""
    reads, code = method.reads(config), method.code
    dyn = reads.get("dynamics", {})
    code = code + (OIM_CODE if OIM_FIELDS[0] in dyn else ()) + (FLOW_CODE if FLOW_FIELDS[0] in dyn else ())
    if masks == "onnx":
        seg = {k: v for k, v in flat_fields(config.segmentation).items() if k not in NOT_IN_KEY}
        reads = {**reads, "segmentation": seg}
        code = code + MASK_CODE
    return reads, code


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


def masks_read(method: Method, requested: str | None, synthetic: bool) -> str | None:
    """The masks a run of ``method`` reads when ``requested`` are asked for (as the study asks for its masks): the
    method's own kind when it has one, else :func:`mask_kind`'s; None when the method needs none."""
    if not method.needs_masks:
        return None
    return mask_kind(method, None if method.masks else requested, synthetic)


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
    return run_orbslam3(args.sequence, args.out, getattr(args, "metrics_json", None),
                        repeats=getattr(args, "repeats", 1) or 1, vocab=getattr(args, "vocab", None),
                        camera=getattr(args, "camera", None),
                        progress=not getattr(args, "quiet", False), masks=getattr(args, "masks", None),
                        online_rate=(getattr(args, "rate", None) or 0.0) if getattr(args, "online", False) else None)


register("orbslam3", lambda config: None, needs_masks=False, runner=_orbslam3_runner,
         reads=sections_read(*ORBSLAM3_SECTIONS), code=ORBSLAM3_CODE,
         help="the real ORB-SLAM3 RGB-D (pyorbslam3) on the sequence, not our engine: d2slam.baselines.orbslam3")


def _orbslam3_masked_runner(args) -> RunRecord:
    """``d2slam run --method orbslam3-masked``: the masks the method reads (``mask_kind``), then ORB-SLAM3's run."""
    seq = open_sequence(args.sequence, **({"camera": args.camera} if getattr(args, "camera", None) else {}))
    args.masks = mask_kind(get_method("orbslam3-masked"), args.masks, synthetic=isinstance(seq, SyntheticSequence))
    return _orbslam3_runner(args)


register("orbslam3-masked", lambda config: None, needs_masks=True, runner=_orbslam3_masked_runner,
         reads=sections_read(*ORBSLAM3_SECTIONS, "masking"), code=ORBSLAM3_CODE,
         help="the real ORB-SLAM3 RGB-D on frames whose person pixels (--masks) are removed: depth 0, RGB filled "
              "(d2slam.baselines.masking)")


def _oracle(config: Config):
    return OracleFilter()


register("oracle", _oracle, needs_masks=True, masks="truth",
         help="upper bound, not a method: the keypoint truth (persons, moved objects while they move) as the filter; "
              "synthetic sequences only")


class _Dynamics:
    """config -> a filter of ``d2slam.dynamics.classifier`` (``kind``: its class name; ``switches`` for
    ``D2SlamFilter``)."""

    def __init__(self, name: str, kind: str = "D2SlamFilter", switches: Switches | None = None):
        self.name, self.kind, self.switches = name, kind, switches

    def __call__(self, config=None):
        cls = getattr(classifier, self.kind)
        if self.switches is None:
            return cls(config, name=self.name)
        return cls(config, self.switches, name=self.name)

    def __repr__(self) -> str:
        return f"dynamics filter factory {self.name!r}"

    def reads(self, config: Config) -> dict:
        """The config a run of the filter reads: the engine's sections and the dynamics fields its modules read
        (the OIM's only with the OIM on, flow's only with flow; the one-module baselines neither)."""
        s = self.switches
        oim, flow = (s.oim, s.flow) if s is not None else (False, False)
        return {**sections_read(*ENGINE_SECTIONS)(config), "dynamics": fields_read(config.dynamics, oim, flow)}



# The paper's method and its ablations (the classifier with one switch off), and the two single-module baselines:
# name -> (factory, needs masks, ``d2slam run --help`` text).
DYNAMICS = {
    "d2slam": (_Dynamics("d2slam", switches=Switches()), True,
               "full D2SLAM: semantic + geometric + Bayesian fusion + object interaction (eq 1-10)"),
    "d2slam-flow": (_Dynamics("d2slam-flow", switches=Switches(flow=True)), True,
                    "ours: d2slam with sub-pixel LK flow correspondences for eq 5 and the edge band "
                    "(FlowConfig.enabled, flow_edge_band)"),
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
    register(_name, _factory, needs_masks=_needs_masks, help=_help, reads=_factory.reads,
             code=ENGINE_CODE + DYNAMICS_CODE)


def _d2slam(config: Config):
    return get_method("d2slam").factory(config)


register("d2slam-sim", _d2slam, needs_masks=True, masks="sim", reads=DYNAMICS["d2slam"][0].reads,
         code=ENGINE_CODE + DYNAMICS_CODE,
         help="d2slam on the simulated segmenter's masks (mask_sim of a synthetic sequence) instead of the real one's")
