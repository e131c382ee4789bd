"""The notebooks' common set-up: a synthetic sequence from the study's cache, a run of one method of the engine on it
with a given kind of masks, and the record of what the keypoint filter saw and decided in every frame.

The module notebooks (02-05) measure the paper's modules on the inputs the engine really gives the filter; this
module gets those inputs in two calls, so that a notebook explains, plots and measures and re-implements nothing
(and picks its sequence by what it should show, ``seed_showing``)::

    seq = development_sequence("walking_xyz", seed_showing("walking_xyz", 30, "people"), 30)
    run = recorded_run(seq, "d2slam")           # masks: the simulated segmenter's (mask_sim/)
    observed = run.cat("observed")              # a diagnostics field over every frame
    err, truth = run.cat("err")[observed], run.cat("truth")[observed]
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from d2slam.config import DEFAULT, Config
from d2slam.data import open_sequence
from d2slam.errors import D2SlamError
from d2slam.eval.keypoints import keypoint_truth
from d2slam.run.methods import get_filter
from d2slam.run.sequence import ensure_vocabulary, run_sequence
from d2slam.segmentation import masks_for, stack_masks
from d2slam.slam.engine import Engine
from d2slam.study.sequences import ensure_sequence
from d2slam.synth import Scene


@dataclass
class FrameRecord:
    """One frame as the keypoint filter saw it: ``inp`` the hook's input (``d2slam.slam.hook.FilterInput``: keypoints,
    their depths, the matches to the previous frame, the masks; None for the method ``none``), ``diag`` the filter's
    diagnostics (``d2slam.dynamics.classifier.FrameDiagnostics``, None for a filter without them) and ``truth`` (N,)
    bool: the keypoints on something that moves (``d2slam.eval.keypoints.keypoint_truth``), None on a sequence
    without per-pixel truth (a real recording)."""

    index: int
    kps: np.ndarray
    inp: object | None
    diag: object | None
    truth: np.ndarray | None


@dataclass
class RecordedRun:
    """A run of ``method``: the engine's ``EngineRun`` and one ``FrameRecord`` per frame."""

    method: str
    result: object = None
    frames: list[FrameRecord] = field(default_factory=list)

    def cat(self, name: str) -> np.ndarray:
        """The diagnostics field ``name`` (``err``, ``observed``, ``belief``, ...) or ``truth``, concatenated over the
        frames: one entry per keypoint of the run."""
        if name == "truth":
            if any(f.truth is None for f in self.frames):
                raise D2SlamError("this run's sequence has no per-pixel truth (a real recording): no keypoint truth")
            return np.concatenate([f.truth for f in self.frames])
        return np.concatenate([getattr(f.diag, name) for f in self.frames])


def config_values(cfg, *names: str) -> str:
    """Markdown naming fields of a config dataclass with their values ("`beta_min` = 0.05, ..."; a dotted name reaches
    into a section: "`ours.p_g_exceed` = 0.7"): prose that relies on defaults states them from the config itself."""
    return ", ".join(f"`{n}` = {functools.reduce(getattr, n.split('.'), cfg)}" for n in names)


def development_sequence(scenario: str, seed: int, frames: int, twin: bool = False, root=None):
    """The synthetic sequence (``SyntheticSequence``) of ``scenario``, ``seed`` and ``frames``, generated once into the
    study's sequence cache (``d2slam.study.sequences.ensure_sequence``, or ``root``) and read from there.
    Notebooks use development seeds (0-99): the study's seeds are never looked at while developing."""
    return open_sequence(ensure_sequence(scenario, seed, frames, twin=twin, root=root, progress=False))


SHOWS = ("people", "moving objects")


def seed_showing(scenario: str, frames: int, what: str = "people", seeds=range(10), config: Config = DEFAULT) -> int:
    """The seed of ``seeds`` whose ``scenario`` sequence of ``frames`` frames shows ``what`` the most, from the scenes'
    plans and camera paths (nothing is rendered): ``people``, the frames x people whose body (the point
    ``SynthEvalConfig.showing_height_m`` above the floor under the pelvis) projects into the image; ``moving
    objects``, the frames x objects moving while their centre projects into it. A notebook picks its sequence by what
    it should show, whatever the scenes' timing. The lowest seed on a tie; a D2SlamError when no seed shows any."""
    if what not in SHOWS:
        raise D2SlamError(f"seed_showing: what must be one of {', '.join(SHOWS)}, not {what!r}")
    scores = {}
    for seed in (int(s) for s in seeds):
        scene = Scene(scenario, seed, frames, cfg=config.synth)
        world_camera = np.linalg.inv(scene.camera.poses(scene.t_rel))
        if what == "people":
            up = np.array([0.0, 0.0, config.synth_eval.showing_height_m])  # world z is up
            tracks = [(np.array([p.root(t)[:3, 3] + up for t in scene.t_rel]), True) for p in scene.people]
        else:
            tracks = [(np.array([o.pose(t)[:3, 3] for t in scene.t_rel]), np.array([o.moving(t) for t in scene.t_rel]))
                      for o in scene.objects]
        scores[seed] = sum(int((_in_image(scene.intrinsics, world_camera, xyz) & shown).sum()) for xyz, shown in tracks)
    best = max(scores, key=lambda s: (scores[s], -s))
    if scores[best] == 0:
        raise D2SlamError(f"no seed of {sorted(scores)} shows {what} within {frames} frames of {scenario}: take more "
                          "frames or other seeds")
    return best


def _in_image(cam, world_camera: np.ndarray, xyz: np.ndarray) -> np.ndarray:
    """(N,) bool: world point ``xyz[i]`` in front of the camera ``world_camera[i]`` (4x4 T_camera_world) of frame i
    and inside the image of the pinhole ``cam`` (fx, fy, cx, cy, width, height)."""
    X = np.einsum("nij,nj->ni", world_camera[:, :3, :3], xyz) + world_camera[:, :3, 3]
    z = X[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        u, v = cam.fx * X[:, 0] / z + cam.cx, cam.fy * X[:, 1] / z + cam.cy
    return (z > 0) & (u >= 0) & (u < cam.width) & (v >= 0) & (v < cam.height)


def mask_provider(seq, kind: str = "sim", config: Config = DEFAULT) -> Callable[[int], np.ndarray]:
    """Frame index -> (n, H, W) bool person masks of ``seq`` (``d2slam.segmentation.masks_for``: ``sim``, ``gt``,
    ``truth`` or ``onnx``), as the engine hands them to its keypoint filter."""
    shape = (seq.camera.height, seq.camera.width)
    return lambda i: stack_masks(masks_for(seq, i, kind, config), shape)


def recorded_run(seq, method: str = "d2slam", config: Config = DEFAULT, masks: str | None = "sim",
                 also: Callable | None = None, inputs: bool = True) -> RecordedRun:
    """Run ``method`` (``d2slam.run.methods``) of the engine on ``seq`` (synthetic, or a real recording) with the
    ``masks`` of :func:`mask_provider` (default the simulated segmenter's: the module notebooks study the modules, not
    the network; None: no masks) and record every frame. ``also(index, keypoints, beliefs, diagnostics)`` is called
    after each frame too (e.g. a ``d2slam.eval.keypoints.KeypointRecorder``). ``inputs=False`` keeps no hook input
    (``FrameRecord.inp`` None): the images it holds take a few MB per frame."""

    truth = callable(getattr(seq, "dynamic_mask", None))
    kfilter = get_filter(method, config)
    ensure_vocabulary(config)
    engine = Engine(seq.camera, config, kfilter)
    run = RecordedRun(method)

    def record(i, kps, beliefs, diag):
        run.frames.append(FrameRecord(i, np.asarray(kps), engine.last_filter_input if inputs else None, diag,
                                      keypoint_truth(kps, seq.dynamic_mask(i)) if truth else None))
        if also is not None:
            also(i, kps, beliefs, diag)

    provider = None if masks is None else mask_provider(seq, masks, config)
    run.result = run_sequence(seq, config, keypoint_filter=kfilter, mask_provider=provider, recorder=record,
                              progress=False, engine=engine)
    return run
