"""The whole config of a run, composed of each part's own (``Config``), and the file users write to change it.

Each part declares its settings beside it, every field with its valid range (:mod:`d2slam.ranges`): the data's
(``d2slam.data.config``), the engine's (``d2slam.slam.config``), the paper's modules' (``d2slam.dynamics.config``),
the segmenter's (``d2slam.segmentation.config``), the synthetic benchmark's (``d2slam.synth.config``), the
evaluation's (``d2slam.eval.config``), the baselines' (``d2slam.baselines.config``), and here the online runs'
(``OnlineConfig``) and the study scheduler's (``StudyConfig``): the run path and the study sit above this module and
read it. ``Config`` composes them as the
sections of a config file (``--config FILE.yaml``: ``section: {field: value}``); ``Config.hash()`` identifies a
configuration in results. ``CliConfig`` composes what the commands around a run announce and check, which changes no
number of a run.

Change a value with ``dataclasses.replace``, ``Config.from_dict`` or :func:`with_overrides`; every way checks it
(``ConfigError``: one line naming ``section.field``, the value and the range).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import typing
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from d2slam.baselines.config import MASK_FILLS, BaselineConfig, MaskedFramesConfig, MaskingConfig
from d2slam.cachefiles import CacheConfig
from d2slam.data.config import DataConfig, DepthCheckConfig, DepthNoise
from d2slam.dynamics.config import DynamicsConfig, FlowConfig, OursConfig, PoseTestConfig
from d2slam.errors import D2SlamError
from d2slam.eval.config import BelongsConfig, EvalConfig
from d2slam.progress import ProgressConfig
from d2slam.ranges import (Checked, ConfigError, Range, build_section, flag, name_sections, one_of, overridden, section,
                           within)
from d2slam.segmentation.config import SegmentationConfig
from d2slam.slam.config import (EngineConfig, KeyframeConfig, LoopConfig, MappingConfig, OrbConfig,
                                RelocalisationConfig, SlamConfig, TrackingConfig)
from d2slam.synth.config import (SYNTH_CAMERA, ActorsConfig, BodyConfig, BodyMotionConfig, ClothConfig, CompositeConfig,
                                 HoldingConfig, SegSimConfig, SittingConfig, SynthConfig, SynthEvalConfig, TwinConfig)

__all__ = ["ActorsConfig", "BaselineConfig", "BelongsConfig", "BodyConfig", "BodyMotionConfig", "CacheConfig", "CLI",
           "CliConfig", "ClothConfig", "CompositeConfig", "Config", "ConfigError", "DataConfig", "DEFAULT",
           "DepthCheckConfig", "DepthNoise", "DynamicsConfig", "EngineConfig", "EvalConfig", "FlowConfig",
           "HoldingConfig", "KeyframeConfig", "LoopConfig", "MASK_FILLS", "MappingConfig", "MaskedFramesConfig",
           "MaskingConfig", "OnlineConfig", "OrbConfig", "OursConfig", "PoseTestConfig", "ProgressConfig", "Range",
           "RelocalisationConfig", "SegSimConfig", "SegmentationConfig", "SittingConfig", "SlamConfig", "StudyConfig",
           "SYNTH_CAMERA", "SynthConfig", "SynthEvalConfig", "TrackingConfig", "TwinConfig", "load_config_file",
           "with_overrides"]


# --------------------------------------------------------------------------------------------------
# The study's scheduler (d2slam.study): longest runs first
# --------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class StudyConfig(Checked):
    # Estimated cost of a run, milliseconds per frame of one run of the method on two busy cores (the real ORB-SLAM3:
    # per repeat, its vocabulary load included), from the per-method worker-seconds of the default study
    # (docs/benchmarks.md); methods not listed cost run_cost_default_ms. Only the order of the runs depends on it:
    # the study starts the longest first (d2slam.study.executors.map_ordered), so that no long run is left alone at
    # the end while the other core idles. Generating or segmenting a sequence costs its frames.
    run_cost_ms: tuple[tuple[str, float], ...] = within((
        ("orbslam3", 69.0), ("orbslam3-masked", 65.0), ("d2slam-flow", 57.0), ("d2slam", 44.0), ("oracle", 44.0),
        ("none", 40.0)), 0.0, 1e7, why='method names and milliseconds per frame')
    run_cost_default_ms: float = within(50.0, 0.0, 1e7)




@dataclass(frozen=True)
class OnlineConfig(Checked):
    """An online run (``d2slam run --online``, ``d2slam.run.online``): frames replayed at the sensor's rate, the
    segmenter in its own thread, a frame the tracker cannot take in time dropped. Offline runs read none of it."""

    # Frames arrive at this rate (Hz); 0: at their own timestamps (the recording's rate and its jitter).
    rate_hz: float = within(0.0, 0.0, 1000.0)
    # The mask a frame reads: "latest", the newest the segmenter has finished (of an earlier frame: tracking never
    # waits for its own), at most mask_max_age_s older, as NGD-SLAM carries its masks forward; "off", none (the
    # segmenter does not run; eq 7 has no mask area: matched keypoints take P_g, unmatched ones 0.5, and eq 8
    # carries their belief). A frame whose mask is too old reads none either.
    masks: str = one_of("latest", "latest", "off")
    mask_max_age_s: float = within(0.2, 0.0, 10.0)
    # Ours, off: a mask of an earlier frame lags its person by the segmenter's latency (3-5 frames at 30 Hz); with
    # mask_motion each person is moved on by its centroid's motion between the segmenter's two newest results,
    # matched to the previous person nearest it within mask_match_px. Off because on development seeds it helped
    # with masks 3 frames late and hurt with masks 5 frames late (docs/online.md).
    mask_motion: bool = flag(False)
    mask_match_px: float = within(80.0, 0.0, 10000.0)
    # Ours, off: with mask_tracks a mask of an earlier frame k is moved, person by person, by the median image motion
    # from frame k to the current frame of the keypoints that lay inside it at frame k (followed through the filter's
    # frame-to-frame matches, as eq 8 follows them); a person with fewer than mask_tracks_min such keypoints stays.
    # Measured: docs/online.md.
    mask_tracks: bool = flag(False)
    mask_tracks_min: int = within(5, 1, 100_000)
    # onnxruntime's intra-op threads of the segmenter's thread (the tracker has the other core).
    segmenter_threads: int = within(1, 1, 64)
    # The segmenter's thread is this much nicer than the tracker's (Linux; 0: the same), so that on a busy machine the
    # tracker, which must keep up with the camera, takes a core first and the segmenter what is left.
    segmenter_nice: int = within(10, 0, 19)
    # Each keyframe's local BA solved in a thread beside tracking, as ORB-SLAM3's LocalMapping thread, and written
    # back (with the keyframe culling) between frames, at the first frame after it is done or before the next
    # keyframe; off: in the tracking thread, in the frame after the keyframe, as offline.
    mapping_thread: bool = flag(True)


@dataclass(frozen=True)
class Config(Checked):
    _RULES = SlamConfig._RULES  # the engine's sections, checked together as the engine reads them

    dynamics: DynamicsConfig = section(DynamicsConfig)
    orb: OrbConfig = section(OrbConfig)
    engine: EngineConfig = section(EngineConfig)
    segmentation: SegmentationConfig = section(SegmentationConfig)
    synth: SynthConfig = section(SynthConfig)
    synth_eval: SynthEvalConfig = section(SynthEvalConfig)
    baseline: BaselineConfig = section(BaselineConfig)
    masking: MaskingConfig = section(MaskingConfig)
    data: DataConfig = section(DataConfig)
    study: StudyConfig = section(StudyConfig)
    evaluation: EvalConfig = section(EvalConfig)
    online: OnlineConfig = section(OnlineConfig)

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "Config":
        """Build a config from a (possibly partial) nested dict; unknown keys are an error."""
        kwargs = {}
        for f in dataclasses.fields(cls):
            if f.name in data:
                kwargs[f.name] = build_section(typing.get_type_hints(cls)[f.name], data[f.name], f.name)
        unknown = set(data) - {f.name for f in dataclasses.fields(cls)}
        if unknown:
            raise ValueError(f"unknown config sections: {sorted(unknown)}")
        return cls(**kwargs)

    def hash(self) -> str:
        blob = json.dumps(self.to_dict(), sort_keys=True, default=list).encode()
        return hashlib.sha256(blob).hexdigest()[:12]


@dataclass(frozen=True)
class CliConfig(Checked):
    """The commands around a run: what they announce and what they check. Not part of ``Config``: nothing here
    changes a run's numbers, so ``Config.hash()`` and the study's run keys do not see it."""

    progress: ProgressConfig = section(ProgressConfig)
    cache: CacheConfig = section(CacheConfig)
    depth_check: DepthCheckConfig = section(DepthCheckConfig)
    belongs: BelongsConfig = section(BelongsConfig)


name_sections(Config)
name_sections(CliConfig, "cli.")
DEFAULT = Config()
CLI = CliConfig()


# Fields that went away when each part got its own sections (one source per quantity), and where what they set
# lives now: a config file that names one is refused in one line saying so. Fields that only moved into a section of
# their part kept their names and are found by name (_moved).
_CAMERA_NOISE = "the camera's depth noise (Camera.depth_noise: a + b (z - c)^2)"
_SYNTH_CAMERA = "the synthetic camera (d2slam.synth.config.SYNTH_CAMERA: TUM freiburg3's intrinsics and depth factor)"
REPLACED = {
    "engine.bf": "the camera's bf (Camera.bf: the TUM camera's, scene.json's or --camera FILE's)",
    "engine.depth_factor": "the camera's depth factor (Camera.depth_factor)",
    "engine.ransac_seed": "engine.seed",
    "engine.pnp_iterations": "engine.relocalisation.relocalisation_pnp_iterations",
    "engine.pnp_reprojection_px": "engine.relocalisation.relocalisation_pnp_px",
    "engine.pnp_confidence": "engine.relocalisation.relocalisation_pnp_confidence",
    "dynamics.flow": "dynamics.flow.enabled",
    "dynamics.pose_test": "dynamics.pose_test.enabled",
    "dynamics.alpha_octave_scale": "orb.scale_factor (dynamics.ours.alpha_at_scale: false for the paper's alpha)",
    "dynamics.depth_patch_radius": "orb.depth_patch_radius (the engine's keypoint depth, which the filter reads)",
    "dynamics.f_ransac_seed": "engine.seed",
    **{f"dynamics.depth_sigma_{k}": _CAMERA_NOISE for k in "abc"},
    **{f"synth.depth_noise_{k}": _CAMERA_NOISE for k in "abc"},
    **{f"synth.{k}": _SYNTH_CAMERA for k in ("fx", "fy", "cx", "cy", "width", "height", "depth_factor")},
    "baseline.orbslam3_th_depth": "engine.th_depth (ORB-SLAM3's ThDepth is the engine's)",
    "cli.depth_ransac_seed": "engine.seed",
}


def _field_paths(cls, prefix: str = "") -> list[str]:
    """Every field of ``cls`` as a config file names it (``engine.keyframes.kf_max_frames``), sections recursed."""
    hints, out = typing.get_type_hints(cls), []
    for f in dataclasses.fields(cls):
        if f.metadata.get("section"):
            out += _field_paths(hints[f.name], f"{prefix}{f.name}.")
        else:
            out.append(prefix + f.name)
    return out


def _check_names(cls, data: dict, prefix: str = "") -> None:
    """A ``ValueError`` for the first key of ``data`` (a config file's ``section: {field: value}``) that ``cls`` has
    not: where a field that moved or went away lives now (``REPLACED``, or the one field of that name), else that it
    is unknown."""
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls)}
    for key, value in data.items():
        name, f = prefix + key, fields.get(key)
        is_section = f is not None and bool(f.metadata.get("section"))
        if f is None or (is_section and not isinstance(value, dict)):
            if name in REPLACED:
                raise ValueError(f"{name} is now {REPLACED[name]}")
            moved = [p for p in _field_paths(Config) if p.rsplit(".", 1)[-1] == key and p.startswith(prefix)]
            if f is None and len(moved) == 1:
                raise ValueError(f"{name} is now {moved[0]}: write it there")
            if f is None and not prefix:
                raise ValueError(f"unknown config section {key!r}; sections: {', '.join(fields)}")
            if f is None:
                raise ValueError(f"unknown {prefix.rstrip('.')} config field {key!r}")
        if is_section and isinstance(value, dict):
            _check_names(hints[key], value, name + ".")


def with_overrides(base: Config, overrides: dict[str, Any]) -> Config:
    """``base`` with the fields of ``overrides`` (``{section: {field: value}}``, nested sections as dicts of their
    own, any subset) replaced; lists become tuples where the field is a tuple. Unknown sections or fields raise
    ``ValueError`` (one that moved or went away: saying where it is now)."""
    if not isinstance(overrides, dict) or not all(isinstance(v, dict) for v in overrides.values()):
        raise ValueError("expected sections of fields, e.g. {dynamics: {z_far: 5.0}}")
    _check_names(Config, overrides)
    return overridden(base, overrides)


def load_config_file(path, base: Config = DEFAULT) -> tuple[Config, dict[str, Any]]:
    """``base`` overridden by a YAML file of ``section: {field: value}`` (``--config FILE.yaml``); returns the config
    and the overrides as read. A bad file is a ``D2SlamError`` naming it."""
    path = Path(path).expanduser()
    if not path.is_file():
        raise D2SlamError("config file not found", path=path)
    try:
        overrides = yaml.safe_load(path.read_text()) or {}
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as exc:
        mark = getattr(exc, "problem_mark", None)
        raise D2SlamError(f"cannot read the config file: {getattr(exc, 'problem', None) or exc}", path=path,
                          line=mark.line + 1 if mark is not None else None) from None
    try:
        config = with_overrides(base, overrides)
    except (TypeError, ValueError) as exc:
        raise D2SlamError(f"bad config file: {exc}", path=path) from None
    return config, overrides
