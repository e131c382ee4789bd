"""The study grid: which runs a study makes, in one deterministic order.

A run is a :class:`RunSpec` ``(scenario, method, seed, frames, twin, source, loop_closing)``: the engine (or real
ORB-SLAM3) with one keypoint-filter method on the synthetic sequence ``scenario`` generated with ``seed`` and
``frames`` frames, or on its *static twin* (same camera path and room, no people, no moved objects) when ``twin`` is
true, with the engine's loop closing on (the default, as ORB-SLAM3) or off. On a real TUM copy (``source="tum"``)
the scenario names a fr3 folder and the seed only seeds the engine's RANSAC. The real recordings of the study
(``source="real"``, ``REAL_SCENARIOS``: the whole TUM fr1/rpy, no people, fetched into the cache by ``d2slam assets
fetch --full-real``) run once per method, with the first seed (it only seeds the engine's RANSAC), over all frames.

The scenario with a return (``office_loop``, ours) runs ``none``, ``d2slam`` and ``oracle`` by default, each with loop
closing on and off (its twin with it on), always at its own length (``d2slam.synth.scene.default_frames``: 1200
frames; fewer would not return), whatever ``frames``.

The real-background set (``COMPOSITE_SCENARIOS``, ``source="composite"``): per seed, the people composited into the
whole real fr1/rpy (every method, as on the fr3 scenarios), and its twins on the real recording itself (``none``,
``d2slam``; ``oracle`` with the composite's truth: the occluded twin), always over all frames, whatever ``frames``.

Online runs (``online``: ``d2slam run --online``, :mod:`d2slam.run.online`): ``none``, ``d2slam`` and the real
ORB-SLAM3 (``ONLINE_METHODS``, those of ``methods``) replayed at the sensor's rate (``OnlineConfig.rate_hz``) with
the segmenter in its own thread and late frames dropped, on the four fr3 walking scenarios (``ONLINE_SCENARIOS``, each
seed, the frames of their offline runs) and on the real recordings (once, as their offline runs); each beside its
offline run in the online table (docs/online.md). The study runs them last, one at a time (``d2slam.study.online``).

Order (rows of ``runs.csv``): scenarios in the paper's order (w/xyz, w/half, w/static, w/rpy, s/static), then the
dynamic sequence before its twin, then the online runs, then seeds ascending, then methods in the order given. The
order never depends on which executor ran the grid or when a run finished.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

from d2slam.assets import real_full
from d2slam.errors import D2SlamError
from d2slam.run.methods import get_method, methods
from d2slam.synth.scene import default_frames, tum_frames

# The five fr3 sequences of the paper's Tables 1-3, in their order, with the paper's row labels; then the
# interaction scenarios of our own (a person carries a box / pushes a chair across the view).
FR3_SCENARIOS = ("walking_xyz", "walking_halfsphere", "walking_static", "walking_rpy", "sitting_static")
INTERACTION_SCENARIOS = ("walking_carry", "walking_push")
LOOP_SCENARIOS = ("office_loop",)  # with a return (ours): loop closing on and off
# Real recordings (d2slam.study.sequences.real_sequence_dir): TUM fr1/rpy, a real Kinect with fast rotations, blur
# and lens distortion and nobody in view, where a keypoint filter must cost nothing.
REAL_SCENARIOS = ("fr1_rpy",)
# The real-background set (source "composite"; d2slam.synth.compositing, docs/real_people.md): the people composited
# into the whole real fr1/rpy (its images, sensor and camera motion real; the people and their truth ours), one
# composite per seed: two people walk in and out of view (real_walking) or one of them carries a box (real_carry).
# Their twins are the real recording itself: `none` and `d2slam` run on it, `oracle` on it with the composite's truth
# as masks (the occluded twin: the people's silhouettes cut out of the real frames).
COMPOSITE_SCENARIOS = ("real_walking", "real_carry")
COMPOSITE_RECORDING = "fr1_rpy"  # the real recording of REAL_SCENARIOS the composites are made of
SCENARIOS = FR3_SCENARIOS + INTERACTION_SCENARIOS + LOOP_SCENARIOS + REAL_SCENARIOS + COMPOSITE_SCENARIOS
LABELS = {"real_walking": "walking on fr1/rpy (composite)", "real_carry": "carry on fr1/rpy (composite)",
          "fr1_rpy": "fr1/rpy (real)", "walking_xyz": "w/xyz", "walking_halfsphere": "w/half", "walking_static": "w/static",
          "walking_rpy": "w/rpy", "sitting_static": "s/static", "walking_carry": "carry (ours)",
          "walking_push": "push (ours)", "office_loop": "loop (ours)"}
TUM_FOLDERS = {s: f"rgbd_dataset_freiburg3_{s}" for s in FR3_SCENARIOS}
DEFAULT_SEEDS = (101, 102, 103)  # CONTRIBUTING.md: study seeds, never tuned on
DEFAULT_FRAMES = 300
BASELINE = "none"  # the engine with the hook off: our in-engine stand-in for ORB-SLAM3
ORBSLAM3 = "orbslam3"  # the real ORB-SLAM3 (not deterministic: repeated, median and spread)
ORBSLAM3_MASKED = "orbslam3-masked"  # the real ORB-SLAM3 on frames with the person masks removed (--masks)
REPEATED = (ORBSLAM3, ORBSLAM3_MASKED)  # the methods that run ORB-SLAM3 (--orbslam3-repeats times)
FULL = "d2slam"
ORACLE = "oracle"  # the keypoint truth as the filter: the ceiling of every method (synthetic data only)
# The masks of every method that does not fix its own (``Method.masks``: the oracle's truth, d2slam-sim's simulated
# segmenter): the real segmenter (YOLOv8n-seg through the mask cache, segmented once per sequence).
STUDY_MASKS = "onnx"
# Methods also run on the static twins: the engine's own floor ("none"), the full method, and the oracle, which on a
# twin reads its dynamic sibling's truth (study.runner): the occluded twin, the people's and moving objects'
# silhouettes cut out of a scene where nothing moves, i.e. what occlusion alone costs the engine.
TWIN_METHODS = (BASELINE, FULL, ORACLE)
# The default methods of the interaction scenarios: the baselines, the paper's method, the ablations that tell what
# the OIM and the geometric module do with objects people move, ours, and the ceiling.
INTERACTION_METHODS = (BASELINE, ORBSLAM3, ORBSLAM3_MASKED, "semantic", "geometric", "no-oim", FULL, "d2slam-flow",
                       ORACLE)
# The default methods of the scenario with a return, each run with the engine's loop closing on and off.
LOOP_METHODS = (BASELINE, FULL, ORACLE)
# Online runs: the engine without a filter, the paper's method with the segmenter in its own thread, and the real
# ORB-SLAM3 under the same camera; on the fr3 walking scenarios (people in view) and on the real recordings (nobody
# in view: what running online costs where a filter has nothing to do).
ONLINE_METHODS = (BASELINE, FULL, ORBSLAM3)
ONLINE_SCENARIOS = ("walking_xyz", "walking_halfsphere", "walking_static", "walking_rpy") + REAL_SCENARIOS


@dataclass(frozen=True, order=False)
class RunSpec:
    scenario: str
    method: str
    seed: int
    frames: int
    twin: bool = False
    # "synth" (generated, cached) | "tum" (a fr3 folder of a TUM copy) | "real" (REAL_SCENARIOS) | "composite"
    # (COMPOSITE_SCENARIOS: generated into the real recording, cached; its twin is the real recording)
    source: str = "synth"
    loop_closing: bool = True  # the engine's loop closing (EngineConfig.loop_closing; ORB-SLAM3 always has its own)
    online: bool = False  # replayed at the sensor's rate, late frames dropped (d2slam.run.online; not deterministic)

    @property
    def label(self) -> str:
        """The paper's row label (``w/xyz``), ``+ twin`` for a static twin."""
        return LABELS.get(self.scenario, self.scenario) + (" (twin)" if self.twin else "")

    @property
    def run_id(self) -> str:
        """A file-name-safe identity, unique in a grid."""
        twin = "_twin" if self.twin else ""
        src = "tum_" if self.source == "tum" else ""  # a real recording's scenario name says it is one
        loop = "" if self.loop_closing else "_noloop"
        online = "_online" if self.online else ""
        return f"{src}{self.scenario}{twin}_s{self.seed}_n{self.frames}_{self.method}{loop}{online}"

    @property
    def sequence_key(self) -> tuple:
        """Runs with the same key share one sequence."""
        return (self.source, self.scenario, self.seed, self.frames, self.twin)

    def to_dict(self) -> dict:
        """The run's fields; ``online`` only for an online run: an offline run's dict, and so its run key
        (``d2slam.study.keys``), names the offline fields alone, and online runs added to a grid re-key none of its
        offline runs."""
        out = asdict(self)
        if not self.online:
            del out["online"]
        return out


def _scenario_rank(name: str) -> int:
    return SCENARIOS.index(name) if name in SCENARIOS else len(SCENARIOS)


def expand_grid(scenarios=SCENARIOS, methods=None, seeds=DEFAULT_SEEDS, frames: int = DEFAULT_FRAMES,
                twin_methods=TWIN_METHODS, source: str = "synth", online_methods=None) -> list[RunSpec]:
    """Every run of the study, in the documented order. ``methods`` default: every registered method plus
    ``orbslam3`` (on the interaction scenarios those of ``INTERACTION_METHODS``, on the scenario with a return those
    of ``LOOP_METHODS``, on a real recording those that need no synthetic truth). ``twin_methods``: the methods also
    run on each static twin (only those of ``methods``; none on real data, which has no twin). On the scenario with a
    return every engine method of ``methods`` runs with loop closing on, then off; a real recording of
    ``REAL_SCENARIOS`` runs each method once (the first seed, all frames). ``online_methods``: the methods also run
    online on ``ONLINE_SCENARIOS`` (only those of ``methods``; ``()``: no online run), after the scenario's offline
    runs; default: ``ONLINE_METHODS`` in the default grid (``methods`` not given) on generated sequences, none where
    the methods are chosen or on a TUM copy (online runs take the machine to themselves: a user asks for them).
    Duplicates in the arguments are dropped (first occurrence kept)."""
    default = methods is None
    if online_methods is None:
        online_methods = ONLINE_METHODS if default and source != "tum" else ()
    if methods is None:
        methods = default_methods(source)
    scenarios, methods, seeds = _unique(scenarios), _unique(methods), _unique(int(s) for s in seeds)
    online = [m for m in methods if m in set(online_methods or ())]
    _check_grid(scenarios, methods, seeds, frames, source, online)
    real_methods = [m for m in methods if m not in _truth_methods()]
    twins = [] if source == "tum" else [m for m in methods if m in set(twin_methods or ())]
    specs = []
    for scenario in sorted(scenarios, key=_scenario_rank):
        if scenario in REAL_SCENARIOS:
            specs += [RunSpec(scenario, m, min(seeds), 0, False, "real") for m in real_methods]
            specs += [RunSpec(scenario, m, min(seeds), 0, False, "real", online=True) for m in online
                      if m in real_methods]
            continue
        if scenario in COMPOSITE_SCENARIOS:  # all frames of the recording; the twin: the recording itself
            for twin, ms in ((False, methods), (True, twins)):
                specs += [RunSpec(scenario, m, seed, 0, twin, "composite") for seed in sorted(seeds) for m in ms]
            continue
        n = frames_of(scenario, frames, source)
        keep = bool
        if default and scenario in INTERACTION_SCENARIOS:
            keep = INTERACTION_METHODS.__contains__
        elif default and scenario in LOOP_SCENARIOS:
            keep = LOOP_METHODS.__contains__
        for twin, ms in ((False, methods), (True, twins)):
            for seed in sorted(seeds):
                for m in ms:
                    if keep(m):
                        specs.append(RunSpec(scenario, m, seed, n, twin, source))
                if scenario in LOOP_SCENARIOS and not twin:
                    specs += [RunSpec(scenario, m, seed, n, twin, source, loop_closing=False) for m in ms
                              if keep(m) and m not in REPEATED]
        if scenario in ONLINE_SCENARIOS:
            specs += [RunSpec(scenario, m, seed, n, False, source, online=True) for seed in sorted(seeds)
                      for m in online]
    return specs


def _check_grid(scenarios: list, methods: list, seeds: list, frames, source: str, online: list) -> None:
    """A grid that cannot run is refused in one line (:func:`expand_grid`'s arguments, duplicates dropped)."""
    if not scenarios or not methods or not seeds:
        raise D2SlamError("the study grid is empty: give at least one scenario, method and seed")
    if frames != "tum" and int(frames) < (0 if source == "tum" else 2):
        raise D2SlamError(f"--frames must be >= 2 (0 = all frames of a TUM folder), got {frames}")
    if source not in ("synth", "tum"):
        raise D2SlamError(f"unknown sequence source {source!r} (synth or tum)")
    if source == "tum":
        truth = _truth_methods()
        truth_only = [m for m in methods if m in truth]
        if truth_only:
            raise D2SlamError(f"{', '.join(truth_only)} need(s) the synthetic truth masks: not on a real TUM copy")
    unknown = [s for s in scenarios if s not in SCENARIOS]
    if unknown:
        raise D2SlamError(f"unknown scenario(s) {', '.join(unknown)}; choose from {', '.join(SCENARIOS)}")
    ours = [s for s in scenarios if s not in FR3_SCENARIOS]
    if source == "tum" and ours:
        raise D2SlamError(f"{', '.join(ours)} is ours, not a TUM sequence: give fr3 scenarios with a TUM copy")
    cannot = [m for m in online if not can_run_online(m)]
    if cannot:
        raise D2SlamError(f"{', '.join(cannot)} cannot run online (online runs: none, the dynamics methods with the "
                          f"real segmenter, and {ORBSLAM3})")


def can_run_online(method: str) -> bool:
    """Whether ``d2slam run --method METHOD --online`` runs: the real ORB-SLAM3, or a keypoint filter of the engine
    that reads the real segmenter's masks or none (``d2slam.run.online.OnlineSLAM``)."""
    if method == ORBSLAM3:
        return True
    if method not in methods():
        return False
    m = get_method(method)
    return m.runner is None and m.masks is None


def default_scenarios() -> list[str]:
    """The study's default scenarios: every synthetic one, and the real recordings whose sequence is in the cache
    (``d2slam assets fetch --full-real``) with the composites into them."""
    return [s for s in SCENARIOS if s not in REAL_SCENARIOS + COMPOSITE_SCENARIOS or real_full() is not None]


def frames_of(scenario: str, frames: int | str, source: str = "synth") -> int:
    """The frames of a scenario's runs: ``frames``, or with ``tum`` its TUM duration (all frames of a real copy); the
    scenario with a return always its own length."""
    if scenario in LOOP_SCENARIOS:
        return default_frames(scenario)
    if frames != "tum":
        return int(frames)

    return 0 if source == "tum" else tum_frames(scenario)


def default_methods(source: str = "synth") -> list[str]:
    """Every method of the run registry (``none`` first) and ``orbslam3``; on a real TUM copy, not those that need
    a synthetic sequence's own masks (``oracle``: truth, ``d2slam-sim``: the simulated segmenter)."""
    names = list(methods())
    if source == "tum":
        truth = _truth_methods()
        names = [m for m in names if m not in truth]
    return names + ([ORBSLAM3] if ORBSLAM3 not in names else [])


def _truth_methods() -> set[str]:
    return {m for m in methods() if get_method(m).masks in ("truth", "sim")}


def _unique(items) -> list:
    out = []
    for x in items:
        if x not in out:
            out.append(x)
    return out
