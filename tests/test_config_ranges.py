"""Every config field declares its valid range beside it, and a value out of it is refused when the config is built
(from a file, a dict, direct construction or ``dataclasses.replace``) in one line naming ``section.field``, the value
and the range; so are the orderings between fields (a minimum above its maximum, ...)."""

from __future__ import annotations

import dataclasses
import math
import typing

import pytest

from d2slam import config as C
from d2slam.config import CLI, DEFAULT, CliConfig, Config, ConfigError, DepthCheckConfig, Range
from d2slam.errors import D2SlamError
from d2slam.ranges import build_section


def _sections(cls=Config, prefix=""):
    """(section class, its name in a config file) of Config, recursively, and the CLI's."""
    out = [(cls, prefix.rstrip("."))] if prefix else []
    for f in dataclasses.fields(cls):
        tp = typing.get_type_hints(cls)[f.name]
        if dataclasses.is_dataclass(tp):
            out += _sections(tp, f"{prefix}{f.name}.")
    return out


SECTIONS = _sections() + _sections(CliConfig, "cli.")
FIELDS = [(cls, name, f) for cls, name in SECTIONS for f in dataclasses.fields(cls)
          if not f.metadata.get("section")]


def _path(name: str, field: str, value) -> dict:
    """``{section: {field: value}}`` for a (possibly nested) section name."""
    d = {field: value}
    for part in reversed(name.split(".")):
        d = {part: d}
    return d


def test_every_field_declares_a_range_and_the_defaults_are_in_it():
    assert len(FIELDS) > 400
    missing = [f"{name}.{f.name}" for _, name, f in FIELDS if not isinstance(f.metadata.get("range"), Range)]
    assert missing == []
    Config(), CliConfig()  # the defaults pass their own checks (and the rules)
    for cls, name, f in FIELDS:
        rng = f.metadata["range"]
        if rng.choices_from is not None:  # checked only when not the default: check the default here
            assert set(f.default) <= set(rng._choices()), f"{name}.{f.name}"


def _leaf(tp, default):
    """(type, default) of the item a tuple field's first value ends with (its last leaf: the float of a
    ``(name, cost)`` pair, the blue of a colour)."""
    first, item_tp = default[0], typing.get_args(tp)[0]
    return (typing.get_args(item_tp)[-1], first[-1]) if isinstance(first, tuple) else (item_tp, first)


def _with_leaf(default, bad):
    """``default`` (a tuple field's value) as a list, its first value's last leaf replaced by ``bad``."""
    first = default[0]
    if isinstance(first, tuple):
        return [list(first[:-1]) + [bad]] + [list(t) for t in default[1:]]
    return [bad] + list(default[1:])


def _outside(rng: Range, tp, default):
    """Values just outside ``rng`` for a field of type ``tp`` (and non-finite ones for a float field)."""
    if typing.get_origin(tp) is tuple:
        leaf_tp, leaf = _leaf(tp, default)
        return [_with_leaf(default, bad) for bad in _outside(dataclasses.replace(rng, ascending=False, length=None),
                                                             leaf_tp, leaf)]
    if rng.choices is not None or rng.choices_from is not None:
        return [] if tp is bool else ["no such choice"]
    if rng.text is not None:
        return []
    integer = tp is int
    out = []
    if rng.lo is not None:
        out.append(rng.lo if rng.lo_open else (rng.lo - 1 if integer else rng.lo - abs(rng.lo) * 1e-3 - 1e-6))
    if rng.hi is not None:
        out.append(rng.hi if rng.hi_open else (rng.hi + 1 if integer else rng.hi + abs(rng.hi) * 1e-3 + 1e-6))
    if not integer:
        out += [math.nan, math.inf, -math.inf]
    return out


@pytest.mark.parametrize("section_cls,section,field", [(c, n, f) for c, n, f in FIELDS], ids=lambda x: getattr(
    x, "name", x if isinstance(x, str) else ""))
def test_a_value_out_of_range_is_one_line_naming_field_value_and_range(section_cls, section, field):
    tp = typing.get_type_hints(section_cls)[field.name]
    rng = field.metadata["range"]
    values = _outside(rng, tp, field.default)
    if typing.get_origin(tp) is tuple and rng.ascending and len(field.default) >= 2 and \
            field.default[0] != field.default[-1]:
        values.append(list(reversed(field.default)))  # descending
    if tp is not bool and rng.text is None:
        assert values, f"{section}.{field.name}: no value outside {rng}"
    for bad in values:
        if section.startswith("cli."):
            with pytest.raises(ConfigError) as exc:
                build_section(CliConfig, _path(section[4:], field.name, bad), "cli")
        else:
            with pytest.raises(ConfigError) as exc:
                Config.from_dict(_path(section, field.name, bad))
        msg = str(exc.value)
        assert msg.startswith(f"{section}.{field.name}") and "\n" not in msg, msg
        assert "is out of range: " in msg or "must be" in msg, msg
        if "is out of range" in msg and not isinstance(bad, (list, str)):
            shown = msg.split(" = ")[1].split(" is out of range")[0]
            assert shown == repr(float(bad) if tp is float else bad), msg


@pytest.mark.parametrize("build", ["from_dict", "replace", "direct"])
def test_every_way_of_building_checks(build):
    def make(**dyn):
        if build == "from_dict":
            return Config.from_dict({"dynamics": dyn})
        if build == "replace":
            return dataclasses.replace(DEFAULT, dynamics=dataclasses.replace(DEFAULT.dynamics, **dyn))
        return C.DynamicsConfig(**dyn)

    with pytest.raises(ConfigError, match=r"^dynamics.z_far = nan is out of range: a finite number in \(0, 20\]$"):
        make(z_far=math.nan)
    with pytest.raises(ConfigError, match=r"^dynamics.dynamic_threshold = -0.5 is out of range: .*\[0, 1\]$"):
        make(dynamic_threshold=-0.5)
    with pytest.raises(ConfigError, match="^dynamics.z_near = 5.0 must be below dynamics.z_far = 4.5$"):
        make(z_near=5.0)
    with pytest.raises(ConfigError, match="^dynamics.z_far must be float, got 'five' "):
        make(z_far="five")
    # an int for a float field is stored as a float: equal configs hash equal however they were built
    built = make(z_far=5)
    cfg = built if isinstance(built, Config) else dataclasses.replace(DEFAULT, dynamics=built)
    assert type(cfg.dynamics.z_far) is float and cfg.hash() == Config.from_dict({"dynamics": {"z_far": 5.0}}).hash()


@pytest.mark.parametrize("overrides,message", [
    ({"orb": {"n_features": 1_000_000_000}}, r"orb.n_features = 1000000000 is out of range: an integer in \[1, "
                                             r"100000\] \(the maximum is more than any frame yields"),
    ({"orb": {"n_features": 0}}, r"orb.n_features = 0 is out of range"),
    ({"orb": {"n_features": 100}}, "orb.n_features = 100 must be at least engine.tracking.init_min_keypoints = 500: "
                                   "the engine could never initialise"),
    ({"engine": {"min_depth": 9.0}}, "engine.min_depth = 9.0 must be below engine.max_depth = 8.0"),
    ({"dynamics": {"alpha_min": 2.0}}, "dynamics.alpha_min = 2.0 must not exceed dynamics.alpha_max = 0.9"),
    ({"dynamics": {"beta_min": 0.5}}, "dynamics.beta_min = 0.5 must not exceed dynamics.beta_max = 0.25"),
    ({"dynamics": {"uncertainty_prob": 1.0}}, r"dynamics.uncertainty_prob = 1.0 is out of range: .*\(0.5, 1\)"),
    ({"orb": {"scale_factor": 4.0}}, r"orb.scale_factor = 4.0 is out of range"),
    ({"orb": {"scale_factor": 2.0, "n_levels": 8}}, r"orb.scale_factor = 2.0 and orb.n_levels = 8: scale_factor\^"),
    ({"orb": {"fast_min_threshold": 30}}, "orb.fast_min_threshold = 30 must not exceed orb.fast_threshold = 20"),
    ({"synth": {"depth_max": 20.0}}, "synth.depth_max = 20.0 times the synthetic camera's depth factor \\(5000\\) must "
                                     "not exceed 65535"),
    ({"synth": {"actors": {"p_sit": 0.9}}}, "synth.actors.p_sit = 0.9, synth.actors.p_exit = 0.06 and "
                                            "synth.actors.p_stand = 0.15 are exclusive choices"),
    ({"synth": {"body": {"shape_low": [0.9, 0.7, 0, 0, 0, 0]}}}, "synth.body.shape_low = .* must not exceed "
                                                                 "synth.body.shape_high"),
    ({"synth": {"actors": {"walk_speed": [1.2, 0.8]}}}, r"synth.actors.walk_speed = \(1.2, 0.8\) is out of range: "
                                                        r".*ascending order"),
    ({"baseline": {"vocab_train_seeds": [101]}}, r"baseline.vocab_train_seeds\[0\] = 101 is out of range: "
                                                 r"an integer in \[900, 999\] \(seeds 900-999"),
    ({"baseline": {"vocab_train_scenarios": ["walking_sideways"]}},
     r"baseline.vocab_train_scenarios\[0\] = 'walking_sideways' is out of range: one of 'walking_xyz'"),
    ({"engine": {"optimizer": "ceres"}}, "engine.optimizer must be one of 'lm', 'g2o', got 'ceres'"),
])
def test_what_the_issue_found_is_refused(overrides, message):
    with pytest.raises(ConfigError, match=message):
        C.with_overrides(DEFAULT, overrides)


def test_a_config_file_names_itself_and_the_field(tmp_path):
    path = tmp_path / "cfg.yaml"
    path.write_text("dynamics: {z_far: .nan}\n")
    with pytest.raises(D2SlamError) as exc:
        C.load_config_file(path)
    assert str(exc.value) == (f"{path}: bad config file: dynamics.z_far = nan is out of range: a finite number in "
                              "(0, 20]")


def test_numpy_numbers_are_taken_as_pythons():
    import numpy as np

    cfg = dataclasses.replace(DEFAULT.orb, n_features=np.int64(1200), scale_factor=np.float32(1.25))
    assert type(cfg.n_features) is int and type(cfg.scale_factor) is float and cfg.n_features == 1200
    with pytest.raises(ConfigError, match="orb.n_features must be int, got True"):
        dataclasses.replace(DEFAULT.orb, n_features=True)


def test_the_cli_section_is_checked_too():
    assert CLI == CliConfig()
    with pytest.raises(ConfigError, match="cli.depth_check.depth_min_baseline_m = 0.6 must be below "
                                          "cli.depth_check.depth_max_baseline_m"):
        DepthCheckConfig(depth_min_baseline_m=0.6)


@pytest.mark.parametrize("written,message", [
    ({"engine": {"kf_max_frames": 40}}, "engine.kf_max_frames is now engine.keyframes.kf_max_frames: write it there"),
    ({"dynamics": {"flow_window": 9}}, "dynamics.flow_window is now dynamics.flow.flow_window: write it there"),
    ({"synth": {"body": {"gait_hip": 0.3}}}, "synth.body.gait_hip is now synth.body.motion.gait_hip: write it there"),
    ({"dynamics": {"flow": True}}, "dynamics.flow is now dynamics.flow.enabled"),
    ({"dynamics": {"depth_patch_radius": 2}}, "dynamics.depth_patch_radius is now orb.depth_patch_radius"),
    ({"dynamics": {"depth_sigma_a": 0.002}}, "dynamics.depth_sigma_a is now the camera's depth noise"),
    ({"synth": {"fx": 500.0}}, "synth.fx is now the synthetic camera"),
    ({"engine": {"ransac_seed": 3}}, "engine.ransac_seed is now engine.seed"),
    ({"engine": {"pnp_iterations": 100}}, "engine.pnp_iterations is now engine.relocalisation.relocalisation_pnp_"),
    ({"baseline": {"orbslam3_th_depth": 30.0}}, "baseline.orbslam3_th_depth is now engine.th_depth"),
])
def test_a_config_file_of_the_old_layout_says_where_each_field_is_now(tmp_path, written, message):
    """A field that moved into its part's section, or went away for one source per quantity: one line naming where
    it is now."""
    import yaml

    path = tmp_path / "old.yaml"
    path.write_text(yaml.safe_dump(written))
    with pytest.raises(D2SlamError) as exc:
        C.load_config_file(path)
    assert str(exc.value).startswith(f"{path}: bad config file: {message}") and "\n" not in str(exc.value)


def test_each_quantity_has_one_source():
    """The quantities that lived under two names or values: the keypoint depth patch, the depth noise, the depth factor,
    ThDepth, the camera, the octave scale of alpha, the RANSAC seeds and the PnP iterations."""
    names = [p.rsplit(".", 1)[-1] for p in C._field_paths(Config) + C._field_paths(CliConfig, "cli.")]
    for once in ("depth_patch_radius", "th_depth", "seed", "pnp_iterations", "scale_factor"):
        assert names.count(once) == 1, once
    for gone in ("depth_sigma_a", "depth_noise_a", "depth_factor", "bf", "fx", "width", "orbslam3_th_depth",
                 "alpha_octave_scale", "ransac_seed", "f_ransac_seed", "depth_ransac_seed"):
        assert gone not in names, gone
