"""The whole config of a run, composed of each part's own (``Config``), and the file users write to change it.

Each part declares its settings beside it, every field with its valid range (:mod:`d2slam.ranges`): the data's
(``d2slam.data.config``), the engine's (``d2slam.slam.config``), the paper's modules' (``d2slam.dynamics.config``),
the segmenter's (``d2slam.segmentation.config``), the synthetic benchmark's (``d2slam.synth.config``), the
evaluation's (``d2slam.eval.config``), the baselines' (``d2slam.baselines.config``), and here the study scheduler's
(``StudyConfig``: the study sits above the run path, which reads this module). ``Config`` composes them as the
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

from d2slam.baselines.config import MASK_FILLS, BaselineConfig, MaskingConfig
from d2slam.cachefiles import CacheConfig
from d2slam.data.config import DataConfig, DepthCheckConfig
from d2slam.dynamics.config import DynamicsConfig
from d2slam.errors import D2SlamError
from d2slam.eval.config import BelongsConfig, EvalConfig
from d2slam.progress import ProgressConfig
from d2slam.ranges import Checked, ConfigError, Range, build_section, name_sections, section, within
from d2slam.segmentation.config import SegmentationConfig
from d2slam.slam.config import EngineConfig, OrbConfig, SlamConfig
from d2slam.synth.config import ActorsConfig, BodyConfig, SynthConfig, SynthEvalConfig, TwinConfig

__all__ = ["ActorsConfig", "BaselineConfig", "BelongsConfig", "BodyConfig", "CacheConfig", "CLI", "CliConfig",
           "Config", "ConfigError", "DataConfig", "DEFAULT", "DepthCheckConfig", "DynamicsConfig", "EngineConfig",
           "EvalConfig", "MASK_FILLS", "MaskingConfig", "OrbConfig", "ProgressConfig", "Range", "SegmentationConfig",
           "StudyConfig", "SynthConfig", "SynthEvalConfig", "TwinConfig", "load_config_file", "with_overrides"]


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


def with_overrides(base: Config, overrides: dict[str, Any]) -> Config:
    """``base`` with the fields of ``overrides`` (``{section: {field: value}}``, any subset) replaced; lists become
    tuples where the field is a tuple. Unknown sections or fields raise ``ValueError``."""
    if not isinstance(overrides, dict) or not all(isinstance(v, dict) for v in overrides.values()):
        raise ValueError("expected sections of fields, e.g. {dynamics: {z_far: 5.0}}")
    data = base.to_dict()
    for name, fields in overrides.items():
        if name not in data:
            raise ValueError(f"unknown config section {name!r}; sections: {', '.join(data)}")
        for key, value in fields.items():
            if key not in data[name]:
                raise ValueError(f"unknown {name} config field {key!r}")
            data[name][key] = value
    return Config.from_dict(data)


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
