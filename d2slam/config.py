"""Every constant of d2slam, in one typed config.

One frozen dataclass per stage; ``Config`` composes them. Paper constants carry their equation number
(our reading of each: ``docs/design.md``). Change a value with
``dataclasses.replace`` or ``Config.from_dict``; ``Config.hash()`` identifies a configuration in results.

Every field declares its valid range beside its default (:func:`within`, :func:`one_of`, :func:`flag`,
:func:`text`, :func:`seed`; a nested section: :func:`section`), and a section lists the orderings between its fields
(``_RULES``: a minimum below its maximum, ...). Both are checked whenever a config is built, from a file
(:func:`load_config_file`), a dict (``Config.from_dict``) or Python (direct construction, ``dataclasses.replace``):
a value of the wrong type or out of its range is one :class:`ConfigError` line naming ``section.field``, the value and
the range (``dynamics.z_far = nan is out of range: a finite number in (0, 20]``). Ints given for a float field are
stored as floats and lists for a tuple field as tuples, so that equal configs hash equal however they were built.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import numbers
import typing
from dataclasses import dataclass, field
from typing import Any, ClassVar, Literal

from d2slam.errors import D2SlamError


# --------------------------------------------------------------------------------------------------
# Valid ranges, declared beside each field and checked when a config is built
# --------------------------------------------------------------------------------------------------
class ConfigError(D2SlamError, ValueError, TypeError):
    """A config value of the wrong type or out of its range (one line naming ``section.field``, the value and the
    range). A ``D2SlamError`` (the command line prints it) and a ``ValueError`` / ``TypeError`` (what the config
    readers catch to name the file)."""


INT_MAX = 2**31 - 1  # seeds and counts that reach C++ (OpenCV, ORB-SLAM3) as a 32-bit int
# The feature budget's bound (docs/inputs.md): OpenCV 5.0's ORB allocates for nfeatures up front and fails with
# std::bad_alloc from 2^29; a 640x480 image of noise yields at most 63,077 ORB keypoints at FAST 20 (8 levels, scale
# 1.2), so no frame fills a budget beyond 100,000 (the extractor asks for n_features x oversample x refill_max).
ORB_FEATURES_WHY = ("the maximum is more than any frame yields: a 640x480 image of noise gives 63,077 ORB "
                    "keypoints; OpenCV's ORB fails from 2^29")
# `orbslam3-masked`'s RGB fills (MaskingConfig.fill; d2slam.baselines.masking).
MASK_FILLS = ("black", "mean", "blur", "pushpull", "telea", "ns")


@dataclass(frozen=True)
class Range:
    """What a field may hold: numbers within ``[lo, hi]`` (an end excluded when ``lo_open`` / ``hi_open``; floats
    finite), ``choices``, any ``text`` (what it is), or a flag. For a tuple: every item (``ascending``: each item at
    least the one before; ``length``: how many items when the type does not fix it). ``why``: what the bound
    comes from, for the message."""

    lo: float | None = None
    hi: float | None = None
    lo_open: bool = False
    hi_open: bool = False
    choices: tuple | None = None
    text: str | None = None
    ascending: bool = False
    length: int | None = None
    why: str = ""
    # ``module:name`` of the tuple of choices, imported only to check a value other than the default (the synthetic
    # scenarios: importing the generator at every config build would cost its start-up)
    choices_from: str | None = None

    def _choices(self) -> tuple | None:
        if self.choices_from is None:
            return self.choices
        import importlib

        module, name = self.choices_from.split(":")
        return tuple(getattr(importlib.import_module(module), name))

    def describe(self, integer: bool = False) -> str:
        if self._choices() is not None:
            return "one of " + ", ".join(repr(c) for c in self._choices())
        if self.text is not None:
            return self.text
        fmt = (lambda v: f"{v:g}" if abs(v) < 1e6 or v != int(v) else str(int(v)))  # noqa: E731
        what = "an integer" if integer else "a finite number"
        if self.lo is not None and self.hi is not None:
            bounds = f"{'(' if self.lo_open else '['}{fmt(self.lo)}, {fmt(self.hi)}{')' if self.hi_open else ']'}"
            out = f"{what} in {bounds}"
        elif self.lo is not None:
            out = f"{what} {'>' if self.lo_open else '>='} {fmt(self.lo)}"
        elif self.hi is not None:
            out = f"{what} {'<' if self.hi_open else '<='} {fmt(self.hi)}"
        else:
            out = what
        if self.length is not None:
            out = f"{self.length} items, each {out}"
        if self.ascending:
            out += ", in ascending order"
        return out + (f" ({self.why})" if self.why else "")

    def holds(self, value) -> bool:
        """Whether a scalar ``value`` (already of the field's type) is in range."""
        if self._choices() is not None:
            return value in self._choices()
        if self.text is not None or isinstance(value, (bool, str)):
            return True
        if isinstance(value, float) and not math.isfinite(value):
            return False
        if self.lo is not None and (value <= self.lo if self.lo_open else value < self.lo):
            return False
        if self.hi is not None and (value >= self.hi if self.hi_open else value > self.hi):
            return False
        return True


def _ranged(default, rng: Range):
    return field(default=default, metadata={"range": rng})


def within(default, lo: float | None = None, hi: float | None = None, *, lo_open: bool = False,
           hi_open: bool = False, ascending: bool = False, length: int | None = None, why: str = ""):
    """A number (or a tuple of numbers, each) in ``[lo, hi]``; ``lo_open`` / ``hi_open`` exclude an end."""
    return _ranged(default, Range(lo, hi, lo_open, hi_open, ascending=ascending, length=length, why=why))


def one_of(default, *choices, lazy: bool = False):
    """One of ``choices`` (or a tuple of them); ``lazy``: the one choice given is the ``module:name`` of the tuple of
    choices, imported only when a value other than the default is checked."""
    if lazy:
        return _ranged(default, Range(choices_from=choices[0]))
    return _ranged(default, Range(choices=tuple(choices)))


def flag(default: bool):
    """True or False."""
    return _ranged(default, Range(choices=(False, True)))


def text(default: str, what: str):
    """Free text: ``what`` it is (a path, ``""`` for the default, ...)."""
    return _ranged(default, Range(text=what))


def seed(default: int):
    """A random seed: an integer in [0, 2^31 - 1]."""
    return within(default, 0, INT_MAX, why="a seed")


def section(cls):
    """A nested section of fields (its own ranges)."""
    return field(default_factory=cls, metadata={"section": True})


def below(a: str, b: str, strict: bool = True) -> tuple:
    """A rule of ``_RULES``: field ``a`` below field ``b`` (``strict``) or at most ``b``; for two tuples, item by
    item."""
    return ((a, b), (lambda x, y: x < y) if strict else (lambda x, y: x <= y),
            "{0} must be below {1}" if strict else "{0} must not exceed {1}")


def rule(names: tuple[str, ...], test, says: str) -> tuple:
    """A rule of ``_RULES``: ``test(*values)`` must hold; ``says``: the message, ``{0}``, ``{1}``, ... standing for
    ``field = value`` of each name (a dotted name reaches into a nested section)."""
    return (names, test, says)


_HINTS: dict[type, dict] = {}
_HERE = "\x00field\x00"  # placeholder for a field's name in a message


def _hints(cls) -> dict:
    if cls not in _HINTS:
        _HINTS[cls] = typing.get_type_hints(cls)
    return _HINTS[cls]


def _section_names() -> dict:
    """Section class -> its name in a config file (``dynamics``, ``synth.body``, ``cli``)."""
    names = {CliConfig: "cli"} if "CliConfig" in globals() else {}
    if "Config" not in globals():
        return names

    def walk(cls, prefix: str) -> None:
        for f in dataclasses.fields(cls):
            tp = _hints(cls)[f.name]
            if dataclasses.is_dataclass(tp):
                names[tp] = prefix + f.name
                walk(tp, prefix + f.name + ".")

    walk(Config, "")
    return names


def _where(obj, name: str) -> str:
    sec = _section_names().get(type(obj))
    return f"{sec}.{name}" if sec else f"{type(obj).__name__}.{name}"


def _shown(value) -> str:
    return repr(value) if not isinstance(value, float) else f"{value!r}"


def _out_of_range(rng: Range, value, tp, where: str, top) -> str | None:
    """The message for ``value`` (of type ``tp``, checked) when it or an item of it is out of ``rng``."""
    if isinstance(value, tuple):
        args = typing.get_args(tp)
        items = args[:1] * len(value) if len(args) == 2 and args[1] is Ellipsis else args
        if rng.length is not None and len(value) != rng.length:
            return f"{where} = {_shown(top)} is out of range: {rng.describe()}"
        for i, (v, t) in enumerate(zip(value, items)):
            msg = _out_of_range(dataclasses.replace(rng, length=None, ascending=False), v, t, f"{where}[{i}]", v)
            if msg:
                return msg
        if rng.ascending and any(b < a for a, b in zip(value, value[1:])):
            return f"{where} = {_shown(top)} is out of range: {rng.describe()}"
        return None
    if not rng.holds(value):
        return f"{where} = {_shown(value)} is out of range: {rng.describe(integer=tp is int)}"
    return None


class _Checked:
    """Base of every config section: ``__post_init__`` checks each field's type and range and the section's
    ``_RULES`` (``(field names, test, what it says)``; :func:`below`, :func:`rule`), raising :class:`ConfigError`."""

    _RULES: ClassVar[tuple] = ()

    def __post_init__(self) -> None:
        hints = _hints(type(self))
        for f in dataclasses.fields(self):
            value, tp = getattr(self, f.name), hints[f.name]
            if f.metadata.get("section"):
                if not isinstance(value, tp):
                    raise ConfigError(f"{_where(self, f.name)} must be a section of fields ({tp.__name__}), got "
                                      f"{value!r}")
                continue
            # the field's name in messages is found only when there is one to give (_HERE stands for it)
            try:
                typed = _typed(value, tp, _HERE)
            except TypeError as exc:
                raise ConfigError(str(exc).replace(_HERE, _where(self, f.name))) from None
            if typed is not value:
                object.__setattr__(self, f.name, typed)
            rng = f.metadata.get("range")  # every field declares one: tests/test_config_ranges.py says which do not
            if rng is None or (rng.choices_from is not None and typed == f.default):
                continue
            msg = _out_of_range(rng, typed, tp, _HERE, typed)
            if msg:
                raise ConfigError(msg.replace(_HERE, _where(self, f.name)))
        for names, test, says in self._RULES:
            values = [self._value(n) for n in names]
            pairs = list(zip(*values)) if all(isinstance(v, tuple) for v in values) else [values]
            if not all(test(*vals) for vals in pairs):
                shown = [f"{_where(self, n) if '.' not in n else n} = {_shown(v)}" for n, v in zip(names, values)]
                raise ConfigError(says.format(*shown))

    def _value(self, name: str):
        obj = self
        for part in name.split("."):
            obj = getattr(obj, part)
        return obj


# --------------------------------------------------------------------------------------------------
# Dynamics: the paper's modules (docs/design.md#depth-adaptive-quantities-eq-2-5-9-10 and the sections after it)
# --------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class DynamicsConfig(_Checked):
    _RULES = (below("z_near", "z_far"), below("beta_min", "beta_max", strict=False),
              below("alpha_min", "alpha_max", strict=False), below("delta_min", "delta_max", strict=False),
              below("gamma_min", "gamma_max", strict=False), below("neighbour_min", "neighbour_k", strict=False))
    # Normalised depth s(z) = clip((z - z_near) / (z_far - z_near), 0, 1): the Kinect range.
    z_near: float = within(0.5, 0.0, 20.0)
    z_far: float = within(4.5, 0.0, 20.0, lo_open=True)
    # eq 2: beta(z) = beta_min + (beta_max - beta_min) s(z), proportional to depth.
    beta_min: float = within(0.05, 0.0, 100.0, lo_open=True)
    beta_max: float = within(0.25, 0.0, 100.0, lo_open=True)
    # eq 2 / fig 2: uncertainty zone where neither state reaches this probability (|d| < ln(p/(1-p)) / beta).
    uncertainty_prob: float = within(0.75, 0.5, 1.0, lo_open=True, hi_open=True)
    # eq 5: alpha(z) = alpha_max - (alpha_max - alpha_min) s(z) pixels, inversely proportional to depth.
    alpha_min: float = within(0.5, 0.0, 100.0, lo_open=True)
    alpha_max: float = within(0.9, 0.0, 100.0, lo_open=True)
    # eq 5 (ours): alpha is expressed at the keypoint's detection scale, alpha(z) * alpha_octave_scale^octave
    # (ORB-SLAM's per-level sigma; = OrbConfig.scale_factor). 1.0 or no octaves from the engine = the paper as printed.
    # Measured: docs/deviations.md.
    alpha_octave_scale: float = within(1.2, 1.0, 2.0)
    # eq 6: sigma of the epipolar-error model, P_g = 1 - exp(-de^2 / (2 sigma^2)) (our reading).
    sigma: float = within(1.0, 0.0, 100.0, lo_open=True)
    # eq 6 (ours): sigma at the keypoint's detection scale too, sigma x 1.2^octave, like alpha (False = the paper), so
    # that a coarse-level match within its scaled alpha does not get P_g > 0.5. Measured: docs/deviations.md.
    sigma_at_scale: bool = flag(True)
    # eq 5 (ours): P_g of a keypoint whose error exceeds alpha; the paper: 1 (certainly dynamic). 0.7 is the
    # reliability of the test, P(dynamic | err > alpha) with equal priors = r_dyn / (r_dyn + r_static) (measured:
    # docs/deviations.md). See geometric.geometric_probability.
    p_g_exceed: float = within(0.7, 0.0, 1.0)
    # eq 7: weight of the geometric term, in the mask's uncertainty zone / in the reliable area.
    omega_uncertain: float = within(0.5, 0.0, 1.0)
    omega_reliable: float = within(0.1, 0.0, 1.0)
    # eq 7: probability when a keypoint has no observation (not matched, outside every mask area).
    p_no_observation: float = within(0.5, 0.0, 1.0)
    # eq 7 (ours): a keypoint with no observation (not matched) takes the mean P_g of its matched neighbours
    # when that is larger than its eq 7 P: of its neighbour_k nearest matched keypoints, those within delta(z) px
    # (eq 9's radius) and neighbour_depth metres, at least neighbour_min of them. False = the paper. See
    # interaction.neighbour_p_g; off: on real frames it spread the false alarms of eq 5 to the unmatched keypoints
    # (measured: docs/deviations.md).
    neighbour_p_g: bool = flag(False)
    neighbour_k: int = within(8, 1, 1000)
    neighbour_depth: float = within(0.15, 0.0, 20.0)
    neighbour_min: int = within(2, 1, 1000)
    # eq 8: symmetric state-transition probability of the Bayesian filter and prior of new keypoints.
    transition: float = within(0.1, 0.0, 1.0)
    prior: float = within(0.5, 0.0, 1.0)
    dynamic_threshold: float = within(0.5, 0.0, 1.0)
    # eq 8 (ours): the likelihood P is clipped to [c, 1 - c] so that one observation of exactly 0 or 1 does not erase
    # the prior (bel would be exactly P whatever bel(q) was).
    likelihood_clip: float = within(1e-3, 0.0, 0.5, hi_open=True)
    # eq 9: delta(z) = delta_a - delta_b z pixels, clipped to [delta_min, delta_max]; rho metres.
    delta_a: float = within(48.0, 0.0, 1000.0)
    delta_b: float = within(4.0, 0.0, 1000.0)
    delta_min: float = within(11.0, 0.0, 1000.0)
    delta_max: float = within(48.0, 0.0, 1000.0)
    rho: float = within(0.7, 0.0, 20.0)
    # eq 9 (our reading): interaction zone = within zone_factor * delta(z_n) px of mask n, |z - z_n| < zone_depth.
    zone_factor: float = within(2.0, 0.0, 100.0)
    zone_depth: float = within(1.0, 0.0, 20.0)
    # eq 9 (ours): z_n = median of the valid depths of mask n sampled on a grid of this stride (1 = every pixel),
    # for speed (measured: docs/deviations.md).
    zone_median_stride: int = within(4, 1, 64)
    # eq 10: gamma(z) = gamma_max - (gamma_max - gamma_min) s(z) pixels.
    gamma_min: float = within(10.0, 0.0, 1000.0)
    gamma_max: float = within(28.0, 0.0, 1000.0)
    # eq 10 (ours): belief given to a static keypoint the OIM turns dynamic (the paper only says "becomes dynamic").
    oim_belief: float = within(0.9, 0.0, 1.0)
    # eq 10 (ours): a keypoint whose own epipolar test passed this frame (matched, err <= alpha) is no OIM
    # candidate: its direct evidence of being static is not overridden by its neighbours'. False = the paper's reading
    # (every keypoint still static after eq 8). See interaction.oim_candidates; measured: docs/deviations.md.
    oim_skip_observed_static: bool = flag(True)
    # eq 10 (ours, off): an unmatched keypoint whose matched neighbours say static (their mean P_g <= 0.5, see
    # neighbour_p_g) is no OIM candidate either. Off because it lowers the recall at a given static precision, the
    # keypoint target (docs/deviations.md).
    oim_skip_neighbour_static: bool = flag(False)
    # eq 9 (ours): a person's interaction zone exists only while the person moves: more of the matched keypoints on
    # its mask fail the geometric test (eq 5 or the pose test) than the thresholds' false alarms explain, a one-sided
    # binomial test at oim_moving_alpha with the false-alarm rate 1 - noise_confidence. A still person (seated behind
    # a desk) moves no object, and each false alarm near it would otherwise turn its neighbours dynamic. A mask with
    # fewer than oim_moving_min matched keypoints cannot be told still and keeps its zone. False = the paper's OIM
    # (every person). See interaction.moving_masks; measured: docs/deviations.md.
    oim_moving_test: bool = flag(True)
    oim_moving_alpha: float = within(0.01, 0.0, 1.0, lo_open=True, hi_open=True)
    oim_moving_min: int = within(5, 1, 100_000)
    # eq 4-5: fundamental matrix by RANSAC (OpenCV), seeded for determinism.
    f_ransac_threshold_px: float = within(1.0, 0.0, 100.0, lo_open=True)
    f_ransac_confidence: float = within(0.999, 0.0, 1.0, lo_open=True, hi_open=True)
    f_ransac_max_iters: int = within(500, 1, 1_000_000)
    f_min_matches: int = within(8, 8, 100_000)
    f_min_static_matches: int = within(30, 0, 100_000)
    f_ransac_seed: int = seed(0)
    # "ransac" (cv2.FM_RANSAC), "magsac" (cv2.USAC_MAGSAC) or "usac_accurate".
    f_ransac_method: str = one_of("ransac", "ransac", "magsac", "usac_accurate")
    # eq 5 (ours, RGB-D): the pose test beside the epipolar error. The epipolar error cannot see motion
    # along the epipolar line (an object carried away from a rotating camera). With depth, the previous 3-D point is
    # moved by the relative pose (PnP-RANSAC on the static-believed matches) and compared with its match: dynamic when
    # the reprojection error exceeds pose_reproj_px x 1.2^octave, or the depth residual
    # |z_p - z_pred| / sqrt(sigma(z_p)^2 + sigma(z_pred)^2) exceeds pose_depth_sigmas; then P_g = max(P_g,
    # p_pose_exceed). 0 turns a test off. See geometric.pose_residuals; measured: docs/deviations.md.
    pose_test: bool = flag(True)
    pose_reproj_px: float = within(4.0, 0.0, 1000.0)
    pose_depth_sigmas: float = within(2.0, 0.0, 1000.0)
    # The depth residual is not tested where the keypoint's depth patch (depth_patch_radius) spans a depth edge: its
    # range above the noise_confidence quantile of the range of that many samples of sigma(z). Such a depth is not the
    # keypoint's surface: on a real Kinect the depth image is taken at its own instant, so under motion an edge's far
    # side is read at the near side's corner (measured: docs/real_data.md). False = every match tested.
    depth_edge_skip: bool = flag(True)
    # P(dynamic | a pose test exceeded) with equal priors, like p_g_exceed (measured: docs/deviations.md).
    p_pose_exceed: float = within(0.9, 0.0, 1.0)
    # Kinect axial depth noise sigma(z) = a + b (z - c)^2 metres (Nguyen et al. 2012; docs/design.md#depth-noise).
    depth_sigma_a: float = within(0.0012, 0.0, 1.0)
    depth_sigma_b: float = within(0.0019, 0.0, 1.0)
    depth_sigma_c: float = within(0.4, 0.0, 20.0)
    # Relative pose of the pose test: cv2.solvePnPRansac with SQPnP (seeded with f_ransac_seed; OpenCV re-estimates
    # the pose on the inliers; no further Levenberg-Marquardt refinement: docs/deviations.md).
    pnp_min_matches: int = within(12, 4, 100_000)
    pnp_ransac_px: float = within(2.0, 0.0, 1000.0, lo_open=True)
    pnp_iterations: int = within(50, 1, 1_000_000)
    pnp_confidence: float = within(0.99, 0.0, 1.0, lo_open=True, hi_open=True)
    # eq 4-6 (ours, off in `d2slam`, on in `d2slam-flow`): sub-pixel correspondences by pyramidal
    # Lucas-Kanade flow (flow.py). Each current keypoint is tracked into the previous image (matched ones starting at
    # their match), kept when the backward track returns within flow_fb_px; eq 5 then measures the tracked position,
    # and unmatched keypoints that track are observed too. Their alpha and eq 6's sigma are not scaled by the octave
    # (the flow's error does not depend on the detection scale). See flow.py; measured: docs/deviations.md.
    flow: bool = flag(False)
    flow_window: int = within(11, 3, 101)
    flow_levels: int = within(3, 0, 10)
    flow_iterations: int = within(10, 1, 1000)
    flow_epsilon: float = within(0.03, 0.0, 10.0, lo_open=True)
    flow_fb_px: float = within(0.5, 0.0, 100.0)
    # Where the flow is used: "all"; "matched" (in a mask area, eq 7's inside or uncertain, only matched keypoints
    # are refined, unmatched ones stay unobserved); "outside" (no flow in a mask area: the masks and the ORB matches
    # decide there, as in the paper: people who sit still are geometrically static, and the flow would observe them;
    # measured: docs/deviations.md).
    flow_area: str = one_of("outside", "all", "matched", "outside")
    # The flow's new matches (unmatched keypoints that tracked) get the previous depth image's robust depth at their
    # tracked position, so the RGB-D pose test runs on them too (flow.flow_matches); off: no depth, eq 5 alone.
    # An object carried along its epipolar lines then does not pass eq 5 as static (measured: docs/deviations.md).
    flow_new_depth: bool = flag(True)
    # eq 7 (ours, with the flow only: on in `d2slam-flow`, off in `d2slam`): a keypoint that nothing
    # observed (not matched, the flow did not track it) and that lies outside every mask but within flow_edge_band px
    # of one (eq 1's signed distance d in (-band, 0)) gets P = max(P, flow_edge_p) (fusion.edge_band). Eq 7 gives it
    # P = P_S < 0.5, so it stayed static. These are person pixels the masks missed (boundary errors of the simulated
    # and real masks) or background at a person's silhouette, where a moving edge breaks the descriptor, so few of
    # them are matched and they spend the feature budget without helping tracking. 0 turns it off. Measured:
    # docs/deviations.md.
    flow_edge_band: float = within(6.0, 0.0, 1000.0)
    flow_edge_p: float = within(0.9, 0.0, 1.0)
    # eq 5-6 and the pose test (ours): each threshold is widened, frame by frame, to at least the noise_confidence
    # quantile of the frame's static residuals (a chi distribution fitted to their median; geometric.widening):
    # alpha(z) (0.5-0.9 px) sits at the noise floor of a sharp sensor whose depth and colour are taken at one instant,
    # and a real Kinect's static residuals are wider and vary with the motion (blur, the depth image's own capture
    # time). False = the paper's fixed thresholds. Measured: docs/real_data.md, docs/deviations.md.
    noise_widening: bool = flag(True)
    noise_confidence: float = within(0.95, 0.5, 1.0, lo_open=True, hi_open=True, why="a quantile above the median")
    # `geometric` ablation: fixed epipolar threshold (pixels) instead of alpha(z).
    fixed_alpha: float = within(0.7, 0.0, 100.0, lo_open=True)
    # Keypoint depth: median of valid pixels in a (2 r + 1)^2 patch.
    depth_patch_radius: int = within(1, 0, 20)


# --------------------------------------------------------------------------------------------------
# SLAM engine (docs/design.md#the-engine-and-its-one-hook; ORB-SLAM3 RGB-D settings)
# --------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class OrbConfig(_Checked):
    # The pyramid's top level: OpenCV fails once a level's image rounds to 0 pixels (a 640x480 frame at scale 4 with 8
    # levels); ORB-SLAM's 1.2^7 = 3.6.
    _RULES = (below("fast_min_threshold", "fast_threshold", strict=False),
              rule(("scale_factor", "n_levels"), lambda s, n: s ** (n - 1) <= 32.0,
                   "{0} and {1}: scale_factor^(n_levels - 1) must not exceed 32 (the top level of the image pyramid "
                   "would keep too few pixels)"))
    n_features: int = within(1000, 1, 100_000, why=ORB_FEATURES_WHY)
    scale_factor: float = within(1.2, 1.0, 2.0, lo_open=True)
    n_levels: int = within(8, 1, 20)
    fast_threshold: int = within(20, 0, 255)
    fast_min_threshold: int = within(7, 0, 255)
    edge_threshold: int = within(19, 0, 100)
    patch_size: int = within(31, 2, 100, why="OpenCV's ORB asserts patchSize >= 2")
    # Spatial bucketing: the image is cut in cells of about this size (pixels) at level 0 (x scale^level above).
    cell_size: int = within(35, 4, 1000)
    # Corners detected per kept feature before bucketing (OpenCV ORB keeps the best by Harris response).
    oversample: float = within(2.0, 1.0, 10.0)
    # Keypoint depth: median of the valid depth pixels in a (2 r + 1)^2 patch around the keypoint.
    depth_patch_radius: int = within(1, 0, 20)


@dataclass(frozen=True)
class EngineConfig(_Checked):
    _RULES = (below("min_depth", "max_depth"), below("desc_th_low", "desc_th_high", strict=False),
              below("kf_min_frames", "kf_max_frames", strict=False),
              below("relocalisation_pnp_candidates", "relocalisation_candidates", strict=False))
    # Virtual stereo: u_R = u - bf / z; points closer than th_depth * b (b = bf / fx) are "close".
    bf: float = within(40.0, 0.0, 10_000.0, lo_open=True)
    th_depth: float = within(40.0, 0.0, 1000.0, lo_open=True)
    # True: every keypoint with valid depth gets u_R and a stereo edge (ORB-SLAM2/3 ComputeStereoFromRGBD); th_depth
    # then only decides which points are "close" (new map points, keyframe decision, keyframe culling). False: far
    # points (beyond th_depth * b) get monocular edges.
    stereo_far_points: bool = flag(True)
    # Ours: with a keypoint filter, each frame extracts OrbConfig.n_features plus as many keypoints as the filter
    # flagged in the previous frame (at most refill_max x n_features), so tracking and mapping keep about n_features
    # usable keypoints, as DynaSLAM's extraction outside the masks does. Without a filter (none, the static twins)
    # nothing changes. Such runs extract every frame themselves (stored features have the fixed budget). Measured:
    # docs/deviations.md.
    refill_filtered: bool = flag(True)
    refill_max: float = within(1.5, 1.0, 10.0)
    depth_factor: float = within(5000.0, 0.0, 1e6, lo_open=True)
    min_depth: float = within(0.1, 0.0, 100.0)
    max_depth: float = within(8.0, 0.0, 100.0, lo_open=True)
    # Stereo observations (u, v, u_R): 0 = ORB-SLAM's information I / sigma_level^2 (u_R as noisy as a stereo match).
    # > 0 (ours, RGB-D): u_R = u - bf / z carries u's error plus the depth's disparity error of this many pixels
    # (optimizer.stereo_information). A Kinect's depth noise grows as sigma_z = k z^2 (k = 1.425e-3 / m, Khoshelham
    # & Elberink 2012), i.e. a constant disparity error bf * k = 0.057 px at bf = 40 (the synthetic sensor's: 0.06-0.08
    # px over 1-3 m); ORB-SLAM's 1 px x scale lets points slide in depth and local BA drag keyframes with them.
    # Measured: docs/deviations.md.
    disparity_sigma_px: float = within(0.057, 0.0, 100.0)
    # Motion-only BA weighs u_R as ORB-SLAM3 does (1 px x scale) in its first pose_opt_coarse_rounds rounds and with
    # disparity_sigma_px after them; 4 = all rounds (ORB-SLAM3 PoseOptimization): the disparity model serves local BA
    # only. With 1, real Kinect frames whose depth image was taken ~15 ms before or after the colour image while the
    # camera turned lost their correct matches as outliers (fr1/rpy), and `none` held on the synthetic walking
    # sequences because people's depths disagree with the map. Measured: docs/real_data.md.
    pose_opt_coarse_rounds: int = within(4, 0, 100)
    # Chi-square thresholds at 95 % (ORB-SLAM): 2 dof mono, 3 dof stereo.
    chi2_mono: float = within(5.991, 0.0, 1000.0, lo_open=True)
    chi2_stereo: float = within(7.815, 0.0, 1000.0, lo_open=True)
    # Motion-only BA: rounds of optimisation with outlier classification, iterations per round.
    pose_opt_rounds: int = within(4, 1, 100)
    pose_opt_iterations: int = within(10, 1, 1000)
    # g2o terminate action: stop a round when chi2 improves less than this
    pose_opt_gain_threshold: float = within(1e-4, 0.0, 1000.0)
    # Matching (ORB-SLAM ORBmatcher): Hamming thresholds, nearest-neighbour ratios, search radii (pixels x scale).
    # motion-model search: below this, search again with twice the radius
    tracking_min_matches: int = within(20, 0, 100_000)
    tracking_min_inliers: int = within(10, 0, 100_000)  # after motion-only BA (motion model / reference keyframe)
    reference_min_matches: int = within(15, 0, 100_000)
    local_map_min_inliers: int = within(30, 0, 100_000)
    relocalisation_min_inliers: int = within(50, 0, 100_000)
    desc_th_high: int = within(100, 0, 256, why='Hamming distance of 256-bit descriptors')
    desc_th_low: int = within(50, 0, 256, why='Hamming distance of 256-bit descriptors')
    nn_ratio_local_map: float = within(0.8, 0.0, 1.0, lo_open=True)
    nn_ratio_reference: float = within(0.7, 0.0, 1.0, lo_open=True)
    nn_ratio_relocalisation: float = within(0.75, 0.0, 1.0, lo_open=True)
    # ORB-SLAM3 RGB-D (non-stereo sensor): th = 15
    search_radius_last_frame: float = within(15.0, 0.0, 1000.0, lo_open=True)
    search_radius_local_map: float = within(3.0, 0.0, 1000.0, lo_open=True)  # ORB-SLAM3 RGB-D: th = 3
    search_radius_relocalisation: float = within(10.0, 0.0, 1000.0, lo_open=True)
    # Local-map search radius on the relocalised frame (ORB-SLAM3 SearchLocalPoints: 15 while the state is still
    # RECENTLY_LOST) and on the frame after it (5).
    search_radius_relocalised: float = within(15.0, 0.0, 1000.0, lo_open=True)
    search_radius_after_relocalisation: float = within(5.0, 0.0, 1000.0, lo_open=True)
    # Local-map search radius factor by viewing angle (ORB-SLAM RadiusByViewingCos): frontal (cos above this) or not.
    local_map_frontal_cos: float = within(0.998, -1.0, 1.0)
    local_map_radius_frontal: float = within(2.5, 0.0, 1000.0, lo_open=True)
    local_map_radius_oblique: float = within(4.0, 0.0, 1000.0, lo_open=True)
    # ORB-SLAM isInFrustum: the point's distance within [0.8 dmin, 1.2 dmax], viewing angle within 60 deg.
    frustum_dmin_factor: float = within(0.8, 0.0, 1.0, lo_open=True)
    frustum_dmax_factor: float = within(1.2, 1.0, 100.0)
    frustum_view_cos: float = within(0.5, -1.0, 1.0)
    rotation_histogram_bins: int = within(30, 1, 360)  # ORB-SLAM HISTO_LENGTH: orientation-consistency histogram
    # keypoint grid cell (px) of searches by projection (ORB-SLAM: 64 x 48 cells)
    search_grid_cell: float = within(10.0, 0.0, 1000.0, lo_open=True)
    check_orientation: bool = flag(True)
    # Initialisation (ORB-SLAM StereoInitialization): keypoints with valid depth needed for the first keyframe.
    init_min_keypoints: int = within(500, 1, 100_000)
    # Keyframe decision (ORB-SLAM3 RGB-D NeedNewKeyFrame): tracked-point ratio, close points, max/min frames.
    kf_tracked_ratio: float = within(0.75, 0.0, 1.0)  # thRefRatio for RGB-D (0.4 while the map has a single keyframe)
    kf_tracked_ratio_first: float = within(0.4, 0.0, 1.0)
    kf_min_frames: int = within(0, 0, 1_000_000)
    kf_max_frames: int = within(30, 0, 1_000_000)
    # Local mapping counts as busy for this many frames after a keyframe (ours: emulates ORB-SLAM3's asynchronous
    # local mapping, during which only the "tracking weak" rule inserts keyframes). 0 = always idle.
    kf_mapping_busy_frames: int = within(3, 0, 1_000_000)
    kf_close_tracked: int = within(100, 0, 100_000)
    kf_close_untracked: int = within(70, 0, 100_000)
    kf_min_inliers: int = within(15, 0, 100_000)
    # c1c: tracking weak when the inliers fall below this share of the reference's points
    kf_weak_ratio: float = within(0.25, 0.0, 1.0)
    # The reference keyframe's points counted by the decision: those with at least this many observations (2 while
    # the map has at most two keyframes).
    kf_ref_min_obs: int = within(3, 1, 1000)
    kf_ref_min_obs_first: int = within(2, 1, 1000)
    # CreateNewKeyFrame: close points added until at least this many (maxPoint)
    kf_new_points_min: int = within(100, 0, 100_000)
    # ... and all closer than this (m) as well (ours): ORB-SLAM3 gets its far points by triangulating keypoints between
    # keyframes (CreateNewMapPoints), which our engine does not do; its keyframes make points from depth up to the
    # Kinect range instead (DynamicsConfig.z_far; 0 = ORB-SLAM3's rule, th_depth * b = 3 m): with people filling the
    # near field, ORB-SLAM3's rule leaves keyframes few static points. The keyframe decision keeps th_depth. Measured:
    # docs/deviations.md.
    kf_new_points_depth: float = within(4.5, 0.0, 100.0)
    # Local mapping.
    local_ba_iterations: int = within(10, 0, 1000)
    # True (ours): after local BA, an observation above the chi-square thresholds whose image residual alone passes
    # the monocular test keeps its image observation, and its keyframe's depth at the keypoint is dropped (u_R = -1);
    # False: the whole observation is erased (ORB-SLAM3, whose 1 px x scale u_R rarely fails where the image passes).
    # With disparity_sigma_px a Kinect depth taken ~15 ms away from the colour image while the camera turns fails, and
    # erasing cost a real keyframe its observations (fr1/rpy: the reference keyframe left with 4 points seen twice, no
    # keyframe for 43 frames). Measured: docs/real_data.md.
    lba_depth_outliers_mono: bool = flag(True)
    # True: a keyframe's local BA and keyframe culling run at the next frame that makes no keyframe, and are skipped
    # when that frame makes one (ORB-SLAM3's local mapping runs beside tracking and skips them while another keyframe
    # waits in its queue, aborting a running BA when one arrives). False: right after the keyframe, every time.
    ba_when_idle: bool = flag(True)
    # Both optimisations: "lm" (compiled Levenberg-Marquardt, d2slam.slam.lm) or "g2o" (the g2opy wheel, same
    # model; its graph is built edge by edge from Python, several times slower).
    optimizer: Literal["lm", "g2o"] = one_of("lm", "lm", "g2o")
    # SearchInNeighbors (observation part, no point merging): the new keyframe and its best covisibles (+ their
    # neighbours) exchange points by projection (radius th x scale, chi-square test, Hamming <= desc_th_low).
    fuse_neighbours: int = within(0, 0, 1000)  # 0 = off; 10 = ORB-SLAM (measured: docs/deviations.md)
    fuse_second_neighbours: int = within(5, 0, 1000)
    fuse_radius: float = within(3.0, 0.0, 1000.0, lo_open=True)
    local_ba_window: int = within(10, 1, 1000)  # covisible keyframes optimised with the new one (best by shared points)
    # keyframes held fixed (best by observations of the local points; ours, for speed)
    local_ba_max_fixed: int = within(5, 0, 1000)
    covisibility_min_shared: int = within(15, 1, 100_000)
    mappoint_found_ratio: float = within(0.25, 0.0, 1.0)
    mappoint_min_obs: int = within(3, 0, 1000)  # ORB-SLAM cnThObs (RGB-D): weighted observations (stereo counts 2)
    mappoint_cull_age: int = within(2, 0, 1000)  # ... checked once a point is this many keyframes old
    # points stay on the recent list (MapPointCulling) for this many keyframes
    mappoint_recent_age: int = within(3, 0, 1000)
    # KeyFrameCulling (ORB-SLAM3): a keyframe is redundant when more than keyframe_redundancy of its close points are
    # seen by more than keyframe_redundant_obs other keyframes (ORB-SLAM3 1.0 counts nObs > 3; its comment and
    # ORB-SLAM2, >= 3) at the same or a finer scale.
    keyframe_redundancy: float = within(0.9, 0.0, 1.0)
    keyframe_redundant_obs: int = within(3, 1, 1000)
    # Tracking the local map: keyframes sharing points with the frame (at most this many) + their covisibles.
    local_map_max_keyframes: int = within(80, 1, 100_000)
    local_map_neighbours: int = within(10, 0, 1000)
    local_map_neighbour_sources: int = within(3, 0, 1000)  # ... covisibles of the best this many keyframes
    # Relocalisation (no DBoW2): descriptor matching against the most recent keyframes, then PnP RANSAC.
    relocalisation_candidates: int = within(10, 1, 1000)
    # ... of which the best by descriptor votes get the PnP attempt (Engine._relocalisation_shortlist).
    relocalisation_pnp_candidates: int = within(3, 1, 1000)
    pnp_iterations: int = within(300, 1, 1_000_000)
    pnp_reprojection_px: float = within(4.0, 0.0, 1000.0, lo_open=True)
    pnp_confidence: float = within(0.99, 0.0, 1.0, lo_open=True, hi_open=True)
    # Keypoint filter (hook): frame-to-frame mutual-nearest matches within this pixel displacement.
    filter_match_window: float = within(80.0, 0.0, 10_000.0, lo_open=True)
    # ... guided instead when the frame's pose is predicted (Engine.filter_matches): previous keypoints moved by the
    # constant-velocity model and searched within this radius (px x scale) on their level +-1, ratio test; fewer
    # than filter_guided_min_matches guided matches -> the window matching above.
    filter_match_guided: bool = flag(True)
    filter_match_radius: float = within(15.0, 0.0, 1000.0, lo_open=True)
    filter_match_nn_ratio: float = within(0.9, 0.0, 1.0, lo_open=True)
    filter_guided_min_matches: int = within(50, 0, 100_000)
    # Map points with a dynamic belief above this are culled (hook output, eq 8).
    mappoint_belief_threshold: float = within(0.5, 0.0, 1.0)
    ransac_seed: int = seed(0)
    # OpenCV thread count, set explicitly (cv2.setNumThreads) for deterministic, reproducible timings.
    cv_threads: int = within(1, 0, 1024)
    # Loop closing (ORB-SLAM3 LoopClosing for RGB-D, run synchronously after local mapping) and place recognition
    # (a DBoW2 keyframe database, which relocalisation also uses). False: the engine without either (relocalisation
    # by descriptor votes over the recent keyframes, relocalisation_candidates).
    loop_closing: bool = flag(True)
    # DBoW2 text vocabulary ("" = the real ORB-SLAM3's: $PYORBSLAM3_VOCAB, else the project's `d2slam vocab build`,
    # built on first use); a keypoint the hook flags dynamic enters no bag of words (loop_dynamic_keypoints).
    vocabulary: str = text("", "a DBoW2 text vocabulary file, or \"\" for the project's")
    bow_levelsup: int = within(4, 0, 10)  # ORB-SLAM3: feature-vector nodes 4 levels above the words
    # True (an ablation: dynamics-unaware place recognition): the keypoints the hook flags dynamic enter the bags of
    # words and the loop's 3D-3D matches all the same (tracking and mapping still leave them out).
    loop_dynamic_keypoints: bool = flag(False)
    # Detection (ORB-SLAM2/3 DetectLoop): not before the map has loop_min_keyframes keyframes nor within loop_gap
    # keyframes of the last loop; candidates score at least the lowest score of the keyframe's covisible keyframes
    # (those sharing >= covisibility_min_shared points, which are never candidates), share more than
    # loop_common_words of the best candidate's common words, and their group (with their loop_group_size best
    # covisibles) accumulates more than loop_group_ratio of the best group's score; a candidate group must recur over
    # loop_consistency consecutive keyframes (ORB-SLAM's covisibility consistency).
    loop_min_keyframes: int = within(10, 0, 100_000)
    loop_gap: int = within(10, 0, 100_000)
    loop_common_words: float = within(0.8, 0.0, 1.0)
    loop_group_size: int = within(10, 0, 1000)
    loop_group_ratio: float = within(0.75, 0.0, 1.0)
    loop_consistency: int = within(3, 0, 1000)
    # Geometry (ORB-SLAM3 Sim3 with the scale fixed for RGB-D): the keyframe's static keypoints with depth matched
    # (2-NN, ratio loop_nn_ratio, Hamming <= desc_th_low) to the points of the candidate and its loop_window best
    # covisibles; 3-point RANSAC of the rigid transform (loop_ransac_iterations, seeded), inliers by the reprojection
    # chi-square (loop_ransac_chi2 x sigma^2, ORB-SLAM's 9.21, in the image and in u_R); at least loop_min_inliers;
    # then the window's points projected with that pose (radius loop_search_radius x scale) and the pose optimised
    # (motion-only BA): at least loop_min_matches inliers accept the loop.
    loop_nn_ratio: float = within(0.75, 0.0, 1.0, lo_open=True)
    loop_window: int = within(10, 0, 1000)
    loop_ransac_iterations: int = within(300, 1, 1_000_000)
    loop_ransac_chi2: float = within(9.21, 0.0, 1000.0, lo_open=True)
    loop_min_inliers: int = within(20, 3, 100_000, why='3-point RANSAC')
    loop_search_radius: float = within(10.0, 0.0, 1000.0, lo_open=True)
    loop_min_matches: int = within(40, 0, 100_000)
    # Correction (ORB-SLAM3 CorrectLoop): the keyframe's covisibles moved with it, the loop window's points fused
    # into them (radius loop_fuse_radius x scale), pose-graph optimisation of the essential graph (spanning tree,
    # covisibility edges of at least essential_min_shared points, loop edges; loop_pgo_iterations of
    # Levenberg-Marquardt, the loop keyframe fixed), then a full BA (loop_full_ba_iterations; the first keyframe
    # fixed).
    loop_fuse_radius: float = within(4.0, 0.0, 1000.0, lo_open=True)
    essential_min_shared: int = within(100, 0, 100_000)
    loop_pgo_iterations: int = within(20, 0, 1000)
    loop_full_ba_iterations: int = within(10, 0, 1000)


# --------------------------------------------------------------------------------------------------
# Segmentation (YOLOv8n-seg person masks through onnxruntime)
# --------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class SegmentationConfig(_Checked):
    # A proposal is a person when its best class is person (class 0) and its person score exceeds this.
    score_threshold: float = within(0.25, 0.0, 1.0, lo_open=True, hi_open=True)
    # IoU above which cv2.dnn.NMSBoxes suppresses the lower-scored person box (Ultralytics default 0.7).
    nms_iou: float = within(0.7, 0.0, 1.0, lo_open=True)
    # sigmoid(coefficients . prototypes), upsampled to the frame, is a person pixel above this.
    mask_threshold: float = within(0.5, 0.0, 1.0, lo_open=True, hi_open=True)
    # Optional dilation of every mask by this radius (pixels, elliptic kernel); 0 = none.
    dilation_px: int = within(0, 0, 100)
    # onnxruntime intra-op threads (inter-op 1, sequential); not part of the mask-cache key.
    intra_op_threads: int = within(2, 0, 256)
    # onnxruntime's intra-op threads spin-wait between operators when True (its default). False: they sleep. Spinning
    # took 1.7x the CPU time of a frame (65 -> 112 ms) and, with two segmenting processes on 2 cores (the study's
    # workers), twice the wall time; not part of the mask-cache key. Measured: docs/benchmarks.md.
    allow_spinning: bool = flag(False)
    # At most this many persons per frame, highest scores first.
    max_persons: int = within(20, 1, 1000)
    # The mask cache file of a sequence is rewritten after this many newly segmented frames (and when the sequence
    # is complete); not part of the mask-cache key.
    cache_flush_frames: int = within(100, 1, 1_000_000)


# --------------------------------------------------------------------------------------------------
# Synthetic benchmark (docs/design.md#the-synthetic-benchmark)
# --------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class BodyConfig(_Checked):
    """Articulated people of the synthetic benchmark (d2slam.synth.bodies): ANNY / MakeHuman bodies."""

    _RULES = (below("shape_low", "shape_high", strict=False), below("waist_height", "neck_height"))
    # ANNY rig (163 bones) and the ranges of its six shape controls in [0, 1]: gender, age, muscle, weight, height,
    # proportions (drawn uniformly per person).
    rig: str = text("default", "the name of an ANNY rig")
    # Mesh decimation factor of the ANNY package (its own quadric simplification, pyfqmr; 1 = the full 13,718-vertex
    # MakeHuman mesh, 2 = 6,863 vertices): posing and llvmpipe's rasterisation grow with the mesh, the silhouettes
    # barely change.
    simplify: float = within(2.0, 1.0, 100.0)
    shape_low: tuple[float, ...] = within((0.0, 0.35, 0.3, 0.3, 0.35, 0.4), 0.0, 1.0, length=6)
    shape_high: tuple[float, ...] = within((1.0, 0.65, 0.7, 0.7, 0.75, 0.6), 0.0, 1.0, length=6)
    # Part boundaries as fractions of the body height (waist: shirt above, trousers below; neck: head above) and
    # the hair cap: head vertices within hair_top_m of the top, or within hair_back_m of it behind the head centre
    # by more than hair_back_y (m).
    waist_height: float = within(0.58, 0.0, 1.0, lo_open=True, hi_open=True)
    neck_height: float = within(0.8, 0.0, 1.0, lo_open=True, hi_open=True)
    hair_top_m: float = within(0.07, 0.0, 1.0)
    hair_back_m: float = within(0.16, 0.0, 1.0)
    hair_back_y: float = within(0.01, -1.0, 1.0)
    # Clothes: RGB palettes (0-255), colour jitter (0-1 units), probability of long sleeves (the garments' patterns
    # are SynthConfig.cloth_*).
    shirt_colours: tuple[tuple[int, int, int], ...] = within((
        (200, 40, 40), (40, 70, 160), (230, 230, 225), (30, 30, 35), (60, 130, 70), (230, 190, 60), (120, 120, 130),
        (150, 60, 140), (240, 140, 60), (90, 160, 200), (180, 170, 150), (110, 40, 40)), 0, 255, why='RGB')
    trousers_colours: tuple[tuple[int, int, int], ...] = within((
        (30, 40, 80), (25, 25, 28), (90, 90, 95), (150, 130, 100), (60, 50, 40), (70, 90, 120), (180, 170, 150)),
        0, 255, why='RGB')
    shoe_colours: tuple[tuple[int, int, int], ...] = within(
        ((20, 20, 20), (230, 230, 230), (90, 60, 40), (60, 60, 70)), 0, 255, why='RGB')
    skin_colours: tuple[tuple[int, int, int], ...] = within((
        (235, 200, 175), (210, 165, 130), (170, 120, 90), (120, 80, 55), (90, 60, 45)), 0, 255, why='RGB')
    hair_colours: tuple[tuple[int, int, int], ...] = within(
        ((30, 25, 20), (90, 60, 35), (160, 120, 70), (120, 120, 120), (20, 20, 20)), 0, 255, why='RGB')
    colour_jitter: float = within(0.06, 0.0, 1.0)
    # Garment textures (d2slam.synth.bodies.uv_layout): one turn round the body (m of texture at the torso's
    # radius) by the body's height (m); texel density of shirt, trousers, shoes, skin, hair relative to
    # SynthConfig.body_texels_per_m; the face on the skin texture: eyes this far below the top of the head, drawn
    # for a head of this radius (the cylindrical map stretches it sideways by turn_m / (2 pi head_radius_m)).
    turn_m: float = within(1.13, 0.0, 10.0, lo_open=True)
    height_m: float = within(1.8, 0.0, 5.0, lo_open=True)
    garment_texels: tuple[float, ...] = within((1.0, 1.0, 0.25, 1.0, 0.5), 0.0, 100.0, lo_open=True, length=5)
    eyes_m: float = within(0.115, 0.0, 1.0)
    head_radius_m: float = within(0.09, 0.0, 1.0, lo_open=True)
    long_sleeve_prob: float = within(0.5, 0.0, 1.0)
    # Baked Lambert shading: ambient share and the light direction (world, towards the light).
    ambient: float = within(0.45, 0.0, 1.0)
    light: tuple[float, float, float] = within((0.35, -0.55, 0.76), -1.0, 1.0)
    # Walking gait (rad): hip swing, knee bend (swing + always), ankle, arm swing, elbow bend (always + swing),
    # arms lowered from the rest A-pose, spine twist, forward lean, head pitch / yaw; per person scaled by a factor
    # in gait_jitter. Stride length (m) per person in stride_m.
    gait_hip: float = within(0.42, -3.1416, 3.1416, why='radians')
    gait_knee: float = within(0.9, -3.1416, 3.1416, why='radians')
    gait_knee0: float = within(0.08, -3.1416, 3.1416, why='radians')
    gait_foot: float = within(0.2, -3.1416, 3.1416, why='radians')
    gait_arm: float = within(0.4, -3.1416, 3.1416, why='radians')
    gait_elbow0: float = within(0.25, -3.1416, 3.1416, why='radians')
    gait_elbow: float = within(0.35, -3.1416, 3.1416, why='radians')
    gait_arm_down: float = within(0.85, -3.1416, 3.1416, why='radians')
    gait_twist: float = within(0.12, -3.1416, 3.1416, why='radians')
    gait_lean: float = within(0.05, -3.1416, 3.1416, why='radians')
    gait_head_pitch: float = within(0.08, -3.1416, 3.1416, why='radians')
    gait_head_yaw: float = within(0.3, -3.1416, 3.1416, why='radians')
    gait_jitter: tuple[float, float] = within((0.8, 1.15), 0.0, 10.0, lo_open=True, ascending=True)
    stride_m: tuple[float, float] = within((1.15, 1.45), 0.0, 10.0, lo_open=True, ascending=True)
    # Carrying a box (upper arm forward, elbow bent) and pushing a chair (arms forward, nearly straight) (rad).
    carry_arm: float = within(0.35, -3.1416, 3.1416, why='radians')
    carry_elbow: float = within(1.25, -3.1416, 3.1416, why='radians')
    push_arm: float = within(1.0, -3.1416, 3.1416, why='radians')
    push_elbow: float = within(0.35, -3.1416, 3.1416, why='radians')
    # Seated people: hip and knee bend, forward lean amplitude, arm rest angle, gesture amplitude, elbow bend,
    # spine twist amplitude (rad); the seat height (m) of the pelvis origin above the floor.
    sit_hip: float = within(1.45, -3.1416, 3.1416, why='radians')
    sit_knee: float = within(1.45, -3.1416, 3.1416, why='radians')
    sit_lean: float = within(0.12, -3.1416, 3.1416, why='radians')
    sit_arm: float = within(0.45, -3.1416, 3.1416, why='radians')
    gesture: float = within(0.5, -3.1416, 3.1416, why='radians')
    sit_elbow: float = within(1.0, -3.1416, 3.1416, why='radians')
    sit_twist: float = within(0.15, -3.1416, 3.1416, why='radians')
    # Seated body placed this far (m) along its forward axis from the chair's centre (negative: towards the back).
    seat_back: float = within(-0.05, -1.0, 1.0)


@dataclass(frozen=True)
class ActorsConfig(_Checked):
    """What the synthetic people do (d2slam.synth.actors): where they walk, how they sit down and get up, how they
    carry a box or push a chair. Floor-plane metres: x right, y away from the camera's home; seconds."""

    _RULES = (rule(("p_sit", "p_exit", "p_stand"), lambda a, b, c: a + b + c <= 1.0,
                   "{0}, {1} and {2} are exclusive choices: their sum must not exceed 1"),
              rule(("p_start_seated", "p_start_exit"), lambda a, b: a + b <= 1.0,
                   "{0} and {1} are exclusive choices: their sum must not exceed 1"))
    # Walking speed (m/s) drawn per leg; carrying or pushing slows people down by hold_speed; speeding up from and
    # slowing down to a stop takes ramp_s; turning in place at turn_rate (rad/s) with small steps (turn_step_m of
    # gait per radian, at turn_gait of the walking amplitude).
    walk_speed: tuple[float, float] = within((0.8, 1.15), 0.0, 10.0, lo_open=True, ascending=True)
    hold_speed: float = within(0.8, 0.0, 1.0, lo_open=True)
    ramp_s: float = within(0.4, 0.0, 100.0)
    turn_rate: float = within(2.2, 0.0, 100.0, lo_open=True)
    turn_step_m: float = within(0.25, 0.0, 10.0)
    turn_gait: float = within(0.35, 0.0, 1.0)
    # Targets: in view (y in view_y, |x| <= view_slope * y: within about 24 degrees of the home camera's axis), or
    # out of view at the sides (|x| in exit_x, y in exit_y); a person counts as out of view beyond |x| > view_slope y
    # + view_margin_m. After leaving the view a person waits away_s before coming back.
    view_y: tuple[float, float] = within((0.9, 1.8), 0.0, 100.0, ascending=True)
    view_slope: float = within(0.45, 0.0, 100.0)
    view_margin_m: float = within(0.3, 0.0, 100.0)
    exit_x: tuple[float, float] = within((1.85, 2.05), 0.0, 100.0, ascending=True)
    exit_y: tuple[float, float] = within((1.0, 2.8), 0.0, 100.0, ascending=True)
    away_s: tuple[float, float] = within((0.3, 1.0), 0.0, 1000.0, ascending=True)
    # The fr3 walkers' choice after each action: sit down on a free chair, walk out of view, stand still (stand_s),
    # else walk to a point in view; at the start: seated (p_start_seated) or out of view (p_start_exit).
    p_sit: float = within(0.15, 0.0, 1.0)
    p_exit: float = within(0.06, 0.0, 1.0)
    p_stand: float = within(0.15, 0.0, 1.0)
    stand_s: tuple[float, float] = within((0.5, 2.0), 0.0, 1000.0, ascending=True)
    p_start_seated: float = within(0.2, 0.0, 1.0)
    p_start_exit: float = within(0.1, 0.0, 1.0)
    # Desk chairs (two, at the desks): centres x = +-desk_chair_x + jitter, y = desk_chair_y + jitter, facing the
    # desk (+y) turned by up to desk_chair_turn rad.
    desk_chair_x: float = within(1.0, 0.0, 100.0)
    desk_chair_y: float = within(2.3, 0.0, 100.0)
    desk_chair_jitter: tuple[float, float] = within((0.25, 0.08), 0.0, 10.0)
    desk_chair_turn: float = within(1.0, -3.1416, 3.1416, why='radians')
    # Sitting down: the person steps in front of the seat (sit_approach_m ahead of it) from beside it (sit_side_m),
    # turns to the chair's heading, sits down and gets up over sit_down_s each, stays seated sit_s. The chair is
    # pushed back by sit_shift_m as they sit down and by stand_shift_m as they get up, plus up to shift_jitter_m
    # sideways and shift_yaw rad of turn. A seated person's root is seat_offset_m behind the chair's centre.
    sit_approach_m: float = within(0.40, 0.0, 10.0)
    sit_side_m: float = within(0.45, 0.0, 10.0)
    sit_down_s: tuple[float, float] = within((1.0, 1.4), 0.0, 100.0, lo_open=True, ascending=True)
    sit_s: tuple[float, float] = within((1.5, 4.0), 0.0, 1000.0, ascending=True)
    sit_shift_m: tuple[float, float] = within((0.02, 0.06), 0.0, 10.0, ascending=True)
    stand_shift_m: tuple[float, float] = within((0.04, 0.10), 0.0, 10.0, ascending=True)
    shift_jitter_m: float = within(0.02, 0.0, 10.0)
    shift_yaw: float = within(0.12, -3.1416, 3.1416, why='radians')
    seat_offset_m: float = within(0.02, -10.0, 10.0)
    # Clearances: furniture (rectangles grown by floor_clearance), chairs (discs), other people, held objects.
    floor_clearance: float = within(0.18, 0.0, 10.0)
    chair_radius: float = within(0.5, 0.0, 10.0)
    # routes from within chair_radius + squeeze_m of a chair may pass it when nothing else does
    squeeze_m: float = within(0.3, 0.0, 10.0)
    person_gap: float = within(0.65, 0.0, 10.0)
    object_gap: float = within(0.55, 0.0, 10.0)
    # ... a person whose last relax_after actions all failed (boxed in) keeps relax_gap of these gaps
    relax_after: int = within(3, 0, 1000)
    relax_gap: float = within(0.65, 0.0, 10.0)
    # Routes: straight, else via a detour sideways at mid-route (m), else along a lane across the room; targets drawn
    # per action, wait after a failed one (s), and the time step of the checks between people (s).
    detours: tuple[float, ...] = within((0.6, 1.0, 1.5), 0.0, 100.0)
    lanes: tuple[float, ...] = within((0.7, 1.3, 1.9), 0.0, 100.0)  # ... else across the room along one of these y
    tries: int = within(20, 1, 100_000)
    retry_wait_s: float = within(0.5, 0.0, 1000.0, lo_open=True)
    check_dt: float = within(0.1, 0.0, 10.0, lo_open=True)
    # Carrying and pushing: the object's pose in the holder's root frame (box in the arms; chair in front, its
    # back to the pusher), the last straight approach behind it, the time to take it or leave it, the least
    # distance it is moved (to the other side of the view, at least move_side of the way to its edge, y in move_y:
    # where the holder goes), the largest
    # turn between the chair's heading and the push, the step away after.
    box_offset: tuple[float, float, float] = within((0.0, 0.42, 1.17), -10.0, 10.0)
    push_offset: tuple[float, float, float] = within((0.0, 0.72, 0.0), -10.0, 10.0)
    take_approach_m: float = within(0.5, 0.0, 10.0)
    take_s: float = within(0.9, 0.0, 100.0)
    move_min_m: float = within(1.0, 0.0, 100.0)
    move_side: float = within(0.3, 0.0, 1.0)
    move_y: tuple[float, float] = within((0.9, 2.3), 0.0, 100.0, ascending=True)
    push_max_turn: float = within(2.0, -3.1416, 3.1416, why='radians')
    leave_m: float = within(0.6, 0.0, 10.0)
    # Interaction scenarios: where the box / chair starts (x within object_x of the camera's axis, either side;
    # y in object_y), facing away from the camera within object_turn rad (taken from the camera's side).
    object_x: tuple[float, float] = within((0.3, 0.9), 0.0, 100.0, ascending=True)
    object_y: tuple[float, float] = within((1.6, 2.2), 0.0, 100.0, ascending=True)
    object_turn: float = within(0.5, -3.1416, 3.1416, why='radians')


@dataclass(frozen=True)
class TwinConfig(_Checked):
    """The synthetic twin of a real recording (``d2slam synth fr1_rpy_twin --on-trajectory TUM_DIR``): our office,
    static, along the recording's ground truth, at its frame and depth times, seen through its camera (the freiburg1
    intrinsics and lens distortion of ``d2slam.data.intrinsics``, from the folder name) by a sensor calibrated against
    the recording. Every value is a measurement of the real fr1/rpy (docs/real_data.md, "The synthetic twin and the
    sensor model", with the commands that print them). Only the twin scenarios read this; the other scenarios'
    sensor is the rest of ``SynthConfig``, unchanged."""

    # Where the recording's first camera pose is put in the room: its optical centre at anchor_xy (m; its height is
    # the recording's own) and its optical axis, seen from above, heading anchor_heading_deg (degrees from +x, +y =
    # 90: towards the desks). The whole trajectory follows rigidly (a rotation about the vertical and a shift).
    # Chosen so that the twin's depths are fr1/rpy's (``d2slam bench realism --anchor``: the depth percentiles of the
    # head's frames, real against twin, over a grid of anchors).
    anchor_xy: tuple[float, float] = within((0.75, 2.9), -100.0, 100.0)
    anchor_heading_deg: float = within(90.0, -360.0, 360.0)
    # The images are rendered through a pinhole and then distorted with the camera's lens model (cv2.remap; RGB
    # bilinear, depth nearest), so that the camera model's undistortion gives back the pinhole geometry.
    distortion: bool = flag(True)
    # RGB exposure (s), measured: the motion blur's extent along the ground truth's image motion against the image
    # speed (d2slam.eval.realism.fit_exposure), its slope. Rendered by averaging sub-frames over the exposure
    # (no cap, unlike blur_max_px's linear kernel).
    exposure: float = within(0.0182, 0.0, 1.0)
    # The RGB images show the scene this long after (negative: before) their timestamps on the ground truth's clock,
    # measured: the epipolar error of the matches against the ground truth's motion is smallest with this shift
    # (d2slam.eval.realism.fit_time_offset).
    rgb_time_shift: float = within(-0.006, -1.0, 1.0)
    # The depth images show the scene this long after (negative: before) their own timestamps (their middle row),
    # measured: the depth of one frame moved into the next by the ground truth's motion agrees best with it with this
    # shift and depth_row_readout (d2slam.eval.realism.depth_consistency). The Kinect stamps depth and colour alike
    # (equal timestamps over fr1/rpy's first 23 frames) but captures its depth earlier: the depth is misregistered
    # with the colour by the camera's motion over the difference.
    depth_time_shift: float = within(-0.025, -1.0, 1.0)
    # The depth's rolling shutter: each depth row this much later (s) than the row above it (the middle row at the
    # shifted timestamp), measured with depth_time_shift by the same agreement (d2slam.eval.realism.depth_consistency
    # with its readout). Rendered row by row from depth sub-frames at most depth_subframe_px of image motion apart.
    depth_row_readout: float = within(7.5e-5, 0.0, 0.01)
    depth_subframe_px: float = within(2.0, 0.0, 1000.0, lo_open=True)
    # Rolling shutter: each RGB row is exposed this much later (s) than the row above it (0: a global shutter),
    # measured with rgb_time_shift: the epipolar error against the ground truth's motion is least with both
    # (d2slam.eval.realism.fit_time_offset; 60 us a row: a 29 ms readout, about a frame).
    row_readout: float = within(6e-5, 0.0, 0.01)
    # RGB noise (grey levels, rgb_noise_sigma's model), set so that the twin's images measure the real recording's
    # noise (d2slam.eval.realism.noise_sigma: 0.49 grey levels on fr1/rpy; on the twin's images it reads 0.49 for this
    # sigma, rounded to whole grey levels, 1.40 for rgb_noise_sigma's 2.0): the Kinect's colour images are smooth.
    rgb_noise_sigma: float = within(0.5, 0.0, 255.0)
    # Sub-frames: as many as keep the image motion between two of them within subframe_px anywhere in the image (at
    # the scene's depths), at most subframes_max; their average is the exposure's image.
    subframe_px: float = within(1.0, 0.0, 1000.0, lo_open=True)
    subframes_max: int = within(40, 1, 10_000)
    # Depth is rendered at the depth image's own instant (its timestamp, the recording's, up to 20 ms from the RGB's,
    # plus depth_time_shift), so that a moving camera's depth is misregistered with its colour as the Kinect's is;
    # False: at the RGB image's instant.
    depth_at_depth_time: bool = flag(True)
    # The Kinect's depth, registered to the colour camera, does not cover the colour image's border: rows at the top
    # and bottom, columns at the left and right (px) where the real depth is a hole in at least half of the frames.
    depth_border: tuple[int, int, int, int] = within((40, 3, 14, 49), 0, 8192)
    # Inside the border, the Kinect's holes are at depth edges (6.6 % of the image, median over frames; 0.26 % are
    # other holes; 6.7 % and 0.22 % on every 5th frame instead of every 2nd), measured (d2slam.eval.realism.hole_kinds,
    # edge_hole_runs: `d2slam bench realism --calibrate`): where the nearer surface is on the
    # right of a depth edge, the hole runs shadow_px (the runs' median along the rows) into the farther surface on the
    # left (the projector's shadow); on the other side, hole_edge_* as for the other scenarios (their 3 px median is
    # the real one there). Other holes: hole_blob_fraction of the image (hole_blob_fraction's model).
    shadow_px: int = within(10, 0, 8192)
    hole_blob_fraction: float = within(0.002, 0.0, 1.0)


@dataclass(frozen=True)
class CompositeConfig(_Checked):
    """People composited into a real recording (``d2slam synth real_walking --on-trajectory TUM_DIR``,
    ``d2slam.synth.composite``, ``d2slam.synth.realroom``): where they may stand in the recording's room, measured
    from its own depth, and how they are put into its images (the twin's camera, timing and sensor,
    ``TwinConfig``). The measurements behind each value: docs/real_people.md. Only the composite scenarios read it."""

    # Fusion of the recording's depth into its ground truth's world: every fuse_stride-th depth image, every
    # fuse_step-th pixel of it.
    fuse_stride: int = within(5, 1, 100_000)
    fuse_step: int = within(4, 1, 64)
    # The floor: the lowest height where at least floor_min_share of the fused points lie within floor_band_m (m), a
    # plane fitted there, at most floor_max_tilt_deg from the world's vertical (the motion capture's Z is up).
    floor_band_m: float = within(0.03, 0.0, 1.0, lo_open=True)
    floor_min_share: float = within(0.01, 0.0, 1.0, lo_open=True)
    floor_max_tilt_deg: float = within(10.0, 0.0, 90.0)
    # Free space: cells of cell_m on the floor, over the fused points' extent plus room_margin_m. A cell is occupied
    # when at least occupied_points fused points lie above it between body_low_m and body_high_m (a standing
    # person's extent); known free when not occupied and either at least floor_points fused points lie on the floor
    # there (within floor_band_m) or, at one of probe_heights_m above it at least, the depth of at least seen_frames
    # fused frames lies at least see_through_m beyond that point (seen through), and at each of the others too or no
    # frame's depth lies within see_through_m of it (no surface was ever seen there: out of view, hidden behind
    # nearer surfaces, holes); never in view when at most
    # never_view_share of the fused frames hold any of its points at view_heights_m (a standing person's feet to
    # head) in their image; out of view when the same holds for their image grown by view_margin_px (the frames
    # between the fused ones turn by up to a few degrees more): where people leave the view to. A person stands on
    # known free or never
    # seen cells at least clearance_m from occupied ones (a person's half width with their arms): where a frame
    # could have seen the space but the depth did not (behind the furniture), nobody stands.
    cell_m: float = within(0.05, 0.0, 10.0, lo_open=True)
    room_margin_m: float = within(1.0, 0.0, 100.0)
    body_low_m: float = within(0.08, 0.0, 10.0)
    body_high_m: float = within(1.9, 0.0, 10.0)
    occupied_points: int = within(20, 1, 10_000_000)
    floor_points: int = within(3, 1, 10_000_000)
    probe_heights_m: tuple[float, ...] = within((0.3, 0.9, 1.5), 0.0, 10.0, ascending=True)
    see_through_m: float = within(0.15, 0.0, 10.0)
    seen_frames: int = within(2, 1, 100_000)
    view_heights_m: tuple[float, ...] = within((0.1, 0.5, 0.9, 1.3, 1.8), 0.0, 10.0, ascending=True)
    view_margin_px: float = within(40.0, 0.0, 10_000.0)
    never_view_share: float = within(0.0, 0.0, 1.0)
    clearance_m: float = within(0.35, 0.0, 10.0)
    # Routes run along the shortest chain of standable cells, their corners rounded by a Gaussian of route_smooth_m
    # (the office's: 0.4 m), which may cut across the cells within route_slack_m of standable ones, never occupied ones.
    route_smooth_m: float = within(0.2, 0.0, 10.0)
    route_slack_m: float = within(0.1, 0.0, 10.0)
    # The camera's operator: the cells within operator_radius_m of the fused frames' camera centres (on the floor)
    # are occupied (a hand-held camera's operator stands there; fr1/rpy's centres stay within 0.11 m of their mean).
    operator_radius_m: float = within(0.4, 0.0, 10.0)
    # Where people are seen (d2slam.synth.composite.person_visibility): a lattice of standable known-free cells every
    # vis_cell_m; a person there is a cylinder of body_half_width_m x body_half_depth_m, body_height_m tall, whose
    # image share is the part of its outline within the image times body_fill times the share of its points there
    # that are seen. Targets in view: cells where a person is seen at least vis_min_coverage in some frame, drawn by
    # how often (the share of the frames) to the power vis_weight_power; exits: cells out of view within
    # exit_reach_m of a target.
    vis_cell_m: float = within(0.2, 0.0, 10.0, lo_open=True)
    body_half_width_m: float = within(0.22, 0.0, 10.0, lo_open=True)
    body_half_depth_m: float = within(0.15, 0.0, 10.0, lo_open=True)
    body_height_m: float = within(1.75, 0.0, 10.0, lo_open=True)
    body_fill: float = within(0.6, 0.0, 1.0, lo_open=True)
    vis_min_coverage: float = within(0.01, 0.0, 1.0)
    vis_weight_power: float = within(2.0, 0.0, 100.0)
    exit_reach_m: float = within(2.0, 0.0, 100.0, lo_open=True)
    # The images (d2slam.synth.compositing). The people's colour is multiplied per channel by the recording's mean
    # colour (the median of every fuse_stride-th frame's mean) over the office's, office_rgb_mean: the mean RGB of the
    # synthetic office's frames (walking_xyz, development seed 0, 60 frames; the people's textures were made for
    # it), so that they take the recording's exposure and white balance.
    office_rgb_mean: tuple[float, float, float] = within((126.2, 117.4, 108.2), 1.0, 255.0)
    # The holes of the Kinect's edge model (SynthConfig.hole_edge_*) are kept within edge_band_px of the edges the
    # people make; the real depth elsewhere is left as it was.
    edge_band_px: int = within(3, 0, 100)
    # The people's colour sub-frames (TwinConfig.subframe_px's rule, over the twin's exposure): at most subframe_px of
    # the camera's image motion apart (measured: docs/real_people.md, the colour against 1 px apart), and at least
    # subframes_min (the people's own motion: a hand at 2 m/s moves about 9 px at 2 m over the exposure).
    subframe_px: float = within(2.0, 0.0, 1000.0, lo_open=True)
    subframes_min: int = within(5, 1, 10_000)


@dataclass(frozen=True)
class SynthConfig(_Checked):
    _RULES = (below("seg_z_near", "seg_z_far"), below("near_plane", "far_plane"),
              below("cx", "width", strict=False), below("cy", "height", strict=False),
              rule(("depth_max", "depth_factor"), lambda z, f: z * f <= 65535.0,
                   "{0} times {1} must not exceed 65535: depth PNGs are 16-bit"),
              rule(("frame_jitter", "fps"), lambda j, fps: j < 0.5 / fps,
                   "{0} must be below half the frame period of {1}: frames would change order"))
    width: int = within(640, 16, 8192)
    height: int = within(480, 16, 8192)
    # Pinhole intrinsics of the synthetic camera: the TUM freiburg3 values (ORB-SLAM3 TUM3.yaml).
    fx: float = within(535.4, 0.0, 100_000.0, lo_open=True)
    fy: float = within(539.2, 0.0, 100_000.0, lo_open=True)
    cx: float = within(320.1, 0.0, 8192.0)
    cy: float = within(247.6, 0.0, 8192.0)
    fps: float = within(30.0, 0.0, 1000.0, lo_open=True)
    gt_rate: float = within(100.0, 0.0, 10_000.0, lo_open=True)
    # TUM-like clock: first RGB timestamp (s) and uniform jitter of each frame time around i / fps (s).
    start_time: float = within(1341846313.592026, 0.0, 1e11)
    frame_jitter: float = within(0.0015, 0.0, 1.0)
    # Ground truth covers the frames with this margin (s) on both ends, like the mocap logs of TUM.
    gt_margin: float = within(0.5, 0.0, 100.0)
    # Kinect-like depth noise sigma(z) = a + b (z - c)^2 metres, quantised to 1 / depth_factor.
    depth_noise_a: float = within(0.0012, 0.0, 1.0)
    depth_noise_b: float = within(0.0019, 0.0, 1.0)
    depth_noise_c: float = within(0.4, 0.0, 20.0)
    # The noise is spatially correlated, as a structured-light sensor's is (it matches a correlation window, so
    # neighbouring pixels share their disparity error): white noise smoothed by a Gaussian of depth_noise_corr_px
    # and rescaled to unit variance, so sigma(z) stays each pixel's standard deviation (0 = independent pixels).
    depth_noise_corr_px: float = within(2.0, 0.0, 100.0)
    depth_factor: float = within(5000.0, 0.0, 65535.0, lo_open=True)
    depth_max: float = within(4.5, 0.0, 100.0, lo_open=True)
    # RGB timestamps vs depth timestamps: depth lags by a uniform offset in this range (seconds).
    # Both images are rendered at the RGB instant (the offset only exercises association).
    depth_time_offset: tuple[float, float] = within((0.002, 0.012), 0.0, 1.0, ascending=True)
    # Depth holes: at depth edges (jump above edge_jump_a + edge_jump_b z metres within 3x3 px), each edge pixel
    # dropped with probability hole_edge_prob after a dilation of hole_edge_dilate px; random small blobs covering
    # about hole_blob_fraction of the image (blobs of about hole_blob_cell px).
    hole_edge_jump_a: float = within(0.05, 0.0, 10.0)
    hole_edge_jump_b: float = within(0.03, 0.0, 10.0)
    hole_edge_prob: float = within(0.6, 0.0, 1.0)
    hole_edge_dilate: int = within(1, 0, 100)
    hole_blob_fraction: float = within(0.01, 0.0, 1.0)
    hole_blob_cell: int = within(12, 1, 1000)
    near_plane: float = within(0.05, 0.0, 100.0, lo_open=True)
    far_plane: float = within(20.0, 0.0, 10_000.0, lo_open=True)
    # llvmpipe rasteriser threads per rendering process (LP_NUM_THREADS unless set): the frames are already spread
    # over the worker processes.
    gl_threads: int = within(1, 0, 256)
    # RGB sensor: Gaussian noise (grey levels), motion blur over the exposure from the camera motion (capped px).
    rgb_noise_sigma: float = within(2.0, 0.0, 255.0)
    exposure: float = within(0.012, 0.0, 1.0)
    blur_max_px: float = within(9.0, 0.0, 1000.0)
    # Texture resolution (texels per metre) of the room and of people / objects.
    room_texels_per_m: float = within(220.0, 0.0, 10_000.0, lo_open=True)
    body_texels_per_m: float = within(420.0, 0.0, 10_000.0, lo_open=True)
    # People: what they do is in ``actors`` (ActorsConfig); their bodies, gait and clothes in ``body`` (BodyConfig).
    # The cloth texture kinds of d2slam.synth.textures (cloth, trousers; the bodies are coloured per vertex by
    # ``body`` instead): probability of a plain shirt, of checks rather than stripes on a patterned one, stripe /
    # check period (m), grey-level contrast of a garment's colours, folds and seams, probability of one printed logo,
    # small printed marks per square metre and their size (m), contrast of logos and marks, fabric blur sigma (m).
    # The carried box and pushed chair keep their busy room textures.
    cloth_plain_prob: float = within(0.15, 0.0, 1.0)
    cloth_check_prob: float = within(0.5, 0.0, 1.0)
    cloth_pattern_m: tuple[float, float] = within((0.05, 0.12), 0.0, 10.0, lo_open=True, ascending=True)
    cloth_contrast: int = within(60, 0, 255)
    cloth_print_prob: float = within(0.4, 0.0, 1.0)
    cloth_marks_per_m2: float = within(200.0, 0.0, 100_000.0)
    cloth_mark_m: tuple[float, float] = within((0.035, 0.065), 0.0, 10.0, lo_open=True, ascending=True)
    cloth_print_contrast: int = within(130, 0, 255)
    cloth_blur_m: float = within(0.0015, 0.0, 1.0)
    # Simulated segmenter (mask_sim): relative boundary error (fraction of the person's apparent size
    # sqrt(bbox area)) grows linearly with normalised depth s(z) = clip((z - seg_z_near) / (seg_z_far - seg_z_near));
    seg_z_near: float = within(0.5, 0.0, 20.0)
    seg_z_far: float = within(4.5, 0.0, 20.0, lo_open=True)
    seg_rel_err_near: float = within(0.012, 0.0, 1.0)
    seg_rel_err_far: float = within(0.09, 0.0, 1.0)
    # ... per-frame miss probability: flicker everywhere, plus far people (z beyond seg_far_start), plus people cut
    # by the image border whose visible fraction of an expected full body is small, plus tiny ones (< min area).
    seg_flicker: float = within(0.03, 0.0, 1.0)
    seg_far_start: float = within(3.0, 0.0, 100.0)
    seg_far_miss: float = within(0.35, 0.0, 1.0)
    seg_cut_miss: float = within(0.5, 0.0, 1.0)
    seg_cut_visible: float = within(0.25, 0.0, 1.0)
    seg_min_area: int = within(250, 0, 100_000_000)
    # Process pool over frames (0 = min(2, cpu count)); per-frame RNGs are seeded from (seed, frame index).
    workers: int = within(0, 0, 1024)
    png_compression: int = within(1, 0, 9)
    # Articulated people (ANNY / MakeHuman bodies) and what they do.
    body: BodyConfig = section(BodyConfig)
    actors: ActorsConfig = section(ActorsConfig)
    # The synthetic twin of a real recording and its calibrated sensor (only the twin scenarios read it).
    twin: TwinConfig = section(TwinConfig)
    # People composited into a real recording (only the composite scenarios read it).
    composite: CompositeConfig = section(CompositeConfig)


@dataclass(frozen=True)
class SynthEvalConfig(_Checked):
    """How the synthetic benchmark is measured against real data and the real segmenter (``d2slam bench realism``,
    ``d2slam bench detection``, notebooks 00 and 02); nothing here changes what the generator writes, so it is kept
    out of the generator version (``study.sequences.generator_version``)."""

    # Realism statistics (`d2slam bench realism`): a pixel is textured when the grey-level standard deviation in its
    # realism_window x realism_window neighbourhood exceeds realism_texture_sd; image corners are FAST corners at
    # ORB-SLAM's initial threshold (realism_fast_threshold), uncapped, unlike the extractor's 1000 keypoints.
    realism_window: int = within(7, 3, 101)
    realism_texture_sd: float = within(8.0, 0.0, 255.0)
    realism_fast_threshold: int = within(20, 0, 255)
    # Motion blur (d2slam.eval.realism.blur_extent): measured in realism_blur_patch-px square patches on a
    # realism_blur_grid (columns, rows) of the image, along the ground truth's image motion, at lags up to
    # realism_blur_max_lag px; a dip of the derivative's autocorrelation below -realism_blur_min_dip is a blur (a
    # weaker one is texture).
    realism_blur_patch: int = within(96, 8, 4096)
    realism_blur_grid: tuple[int, int] = within((5, 4), 1, 100)
    realism_blur_max_lag: int = within(48, 1, 4096)
    realism_blur_min_dip: float = within(0.1, 0.0, 1.0)
    # Real against twin (`d2slam bench realism --real SEQ --twin SEQ`, d2slam.eval.realism.measure): per-frame image
    # statistics on every realism_stride-th frame; epipolar errors are also given by keypoint depth (inner bin
    # edges, m) and by image radius (px from the principal point).
    realism_stride: int = within(5, 1, 100_000)
    realism_depth_bins: tuple[float, ...] = within((1.0, 1.5, 2.5), 0.0, 100.0, ascending=True)
    realism_radius_bins: tuple[float, ...] = within((100.0, 200.0, 300.0), 0.0, 10_000.0, ascending=True)
    # Segmenter against the truth (`d2slam bench detection`): people covering at least seg_eval_min_area of the image
    # count; detected when a predicted mask has IoU >= seg_eval_iou with the visible mask; target detection rate per
    # scenario; inner edges (m) of the IoU-by-depth table; the boundary error of a person's best mask is the mean and
    # this percentile of the symmetric distances (px) between the two masks' boundaries.
    seg_eval_min_area: float = within(0.03, 0.0, 1.0)
    seg_eval_iou: float = within(0.5, 0.0, 1.0, lo_open=True)
    seg_eval_target: float = within(0.95, 0.0, 1.0)
    seg_eval_depth_bins: tuple[float, ...] = within((1.5, 2.5, 3.5), 0.0, 100.0, ascending=True)
    seg_eval_boundary_percentile: float = within(90.0, 0.0, 100.0)
    # The benchmark against the published record on the real fr3 sequences (`d2slam bench calibration`,
    # d2slam.study.calibration): on the walking scenarios the masks-only baselines and d2slam at least
    # calib_improvement % better than raw ORB-SLAM3 (median over seeds; the published mask-based methods: 93-98 %),
    # raw ORB-SLAM3 at least calib_orbslam3_min_m (w/static: calib_orbslam3_static_min_m; published 0.28-0.69 and
    # 0.02-0.10 m); on s/static raw ORB-SLAM3 at most calib_sitting_max_m (published about 0.009 m).
    calib_improvement: float = within(90.0, 0.0, 100.0)
    calib_orbslam3_min_m: float = within(0.1, 0.0, 100.0)
    calib_orbslam3_static_min_m: float = within(0.02, 0.0, 100.0)
    calib_sitting_max_m: float = within(0.02, 0.0, 100.0)
    # Notebooks pick the development seed that shows what they are about (d2slam.notebook.seed_showing): a person is
    # in view when the point this high (m) above the floor under the pelvis (a standing adult's waist) projects into
    # the image.
    showing_height_m: float = within(1.0, 0.0, 10.0)


# --------------------------------------------------------------------------------------------------
# Baselines: the real ORB-SLAM3 (pyorbslam3) and the DBoW2 vocabulary the project builds for it
# --------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class BaselineConfig(_Checked):
    _RULES = (below("vocab_levelsup", "vocab_levels", strict=False),)
    # DBoW2 tree: branching k, depth L (the official ORBvoc.txt: 10, 6), ORB-SLAM3's FeatureVector level
    # (levelsup = 4 levels above the leaves), k-majority iterations per level, training seed.
    vocab_k: int = within(10, 2, 20, why="ORB-SLAM3's vocabulary loader")
    vocab_levels: int = within(6, 1, 10, why="ORB-SLAM3's vocabulary loader")
    vocab_levelsup: int = within(4, 0, 10)
    vocab_max_iter: int = within(10, 1, 1000)
    vocab_seed: int = seed(0)
    # Synthetic training sequences (seeds 900-999 are reserved for the vocabulary): seeds, scenarios, frames per
    # sequence, every n-th frame used.
    vocab_train_seeds: tuple[int, ...] = within(
        (900, 901), 900, 999, why="seeds 900-999 are the vocabulary's; benchmarks use the others")
    vocab_train_scenarios: tuple[str, ...] = one_of(
        ("walking_xyz", "walking_halfsphere", "walking_rpy", "sitting_static"), "d2slam.synth.scene:SCENARIOS",
        lazy=True)
    vocab_train_frames: int = within(60, 1, 100_000)
    vocab_train_stride: int = within(6, 1, 100_000)
    # A build is announced with its estimate: a + b x frames to render + c x training images (CPU seconds, measured:
    # docs/orbslam3_baseline.md); without a terminal each stage logs a line on stderr every this many seconds.
    vocab_estimate_s: tuple[float, float, float] = within((3.0, 0.15, 0.15), 0.0, 10_000.0)
    vocab_log_interval_s: float = within(5.0, 0.0, 10_000.0)
    # ORB-SLAM3 run: camera fps written in the settings, repeats of the study (its threads are not deterministic: the
    # study reports the median and spread of the repeats per sequence; docs/deviations.md), subprocess time limits
    # (vocabulary load + per frame).
    orbslam3_fps: float = within(30.0, 0.0, 1000.0, lo_open=True)
    # ORB-SLAM3's own TUM setting (Stereo.ThDepth: close points within 40 b = 3 m; it triangulates the far ones),
    # not our engine's EngineConfig.th_depth.
    orbslam3_th_depth: float = within(40.0, 0.0, 1000.0, lo_open=True)
    orbslam3_repeats: int = within(3, 1, 100)
    orbslam3_load_timeout_s: float = within(180.0, 0.0, 100_000.0, lo_open=True)
    orbslam3_frame_timeout_s: float = within(2.0, 0.0, 10_000.0, lo_open=True)
    # Repeated runs read frames decoded once (and people removed once) from a frame store in this folder (memory-
    # backed; the run's work folder when it lacks room), at most this many MB (RGB + float32 depth: 2.1 MB a
    # 640x480 frame); beyond it each run decodes its frames (docs/orbslam3_baseline.md: per-run overhead).
    orbslam3_frame_store_dir: str = text("/dev/shm", "a folder (memory-backed)")
    orbslam3_frame_store_mb: int = within(2048, 0, 10_000_000)


@dataclass(frozen=True)
class MaskingConfig(_Checked):
    # `orbslam3-masked` (d2slam.baselines.masking): the person masks (the union of a frame's instances) are grown by
    # dilate_px pixels (elliptic kernel), then the depth there is set to 0 (invalid) and the RGB there is filled.
    # See docs/masking.md for the measurements behind the choice.
    dilate_px: int = within(4, 0, 1000)
    # RGB fill: "black" (0), "mean" (the frame's mean colour outside the region), "blur" (normalised convolution of
    # the pixels outside the region, Gaussian of sigma blur_px / 3 at 1/4 resolution; the mean colour where none is
    # within reach), "pushpull" (a Gaussian pyramid of the pixels outside, pushpull_levels deep, filled coarse to
    # fine), "telea" / "ns" (OpenCV inpainting, cv2.INPAINT_TELEA / cv2.INPAINT_NS, with inpaint_radius px at
    # 1/inpaint_scale of the resolution).
    fill: str = one_of("pushpull", *MASK_FILLS)
    blur_px: int = within(31, 1, 1000)
    pushpull_levels: int = within(6, 1, 20)
    inpaint_radius: float = within(3.0, 0.0, 1000.0, lo_open=True)
    inpaint_scale: int = within(8, 1, 64)
    # The blur, pushpull and inpainting fills are computed on the region's bounding box grown by this many pixels.
    crop_margin_px: int = within(32, 0, 10_000)
    # `d2slam bench masking`: a keypoint is on the boundary when within this many pixels of the filled region's edge.
    boundary_band_px: int = within(3, 0, 1000)


# --------------------------------------------------------------------------------------------------
# The study's scheduler (d2slam.study): longest runs first
# --------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class StudyConfig(_Checked):
    # Estimated cost of a run, milliseconds per frame of one run of the method on two busy cores (the real ORB-SLAM3:
    # per repeat, its vocabulary load included), from the per-method worker-seconds of the default study
    # (docs/benchmarks.md); methods not listed cost run_cost_default_ms. Only the order of the runs depends on it:
    # the study starts the longest first (d2slam.study.executors.map_ordered), so that no long run is left alone at
    # the end while the other core idles. Generating or segmenting a sequence costs its frames.
    run_cost_ms: tuple[tuple[str, float], ...] = within((
        ("orbslam3", 69.0), ("orbslam3-masked", 65.0), ("d2slam-flow", 57.0), ("d2slam", 44.0), ("oracle", 44.0),
        ("none", 40.0)), 0.0, 1e7, why='method names and milliseconds per frame')
    run_cost_default_ms: float = within(50.0, 0.0, 1e7)


# --------------------------------------------------------------------------------------------------
# Data: TUM reading and downloading (docs/design.md#tum-data)
# --------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class DataConfig(_Checked):
    # RGB/depth association tolerance (s), TUM associate.py convention (strict <).
    max_dt: float = within(0.02, 0.0, 10.0, lo_open=True)
    # Ground-truth interpolation refuses to bridge gaps longer than this (s); TUM mocap runs at 100 Hz.
    gt_max_gap: float = within(0.1, 0.0, 100.0, lo_open=True)
    # Trajectory validation: |q| - 1 tolerance and rotation orthonormality tolerance.
    quaternion_norm_tolerance: float = within(1e-2, 0.0, 1.0, lo_open=True)
    rotation_tolerance: float = within(1e-5, 0.0, 1.0, lo_open=True)
    # `d2slam download`: connect/read timeout (s) so an unreachable server fails fast.
    download_timeout: float = within(10.0, 0.0, 10_000.0, lo_open=True)
    # Depth-scale check of `d2slam run` without ground truth or camera motion (else CliConfig.depth_*): the median valid
    # depth (m) of the first depth_check_frames frames must lie in depth_median_range (an indoor RGB-D scene; metres
    # read as 1/5000 m move it out, not every factor of 5); otherwise a warning names the factor that would bring it
    # in.
    depth_check_frames: int = within(5, 1, 100_000)
    depth_median_range: tuple[float, float] = within((0.7, 10.0), 0.0, 1000.0, lo_open=True, ascending=True)
    # Depth factors the warning suggests: millimetres, TUM's 1/5000 m, metres.
    depth_factor_candidates: tuple[float, ...] = within((1000.0, 5000.0, 1.0), 0.0, 1e6, lo_open=True)


# --------------------------------------------------------------------------------------------------
# The command line around a run: what it announces and what it checks. Not part of ``Config``: nothing here changes
# a run's numbers, so ``Config.hash()`` and the study's run keys do not see it.
# --------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class CliConfig(_Checked):
    _RULES = (below("depth_min_baseline_m", "depth_max_baseline_m"),)
    # One-off costs (generating a synthetic sequence, segmenting a sequence into the mask cache) and the study's phases
    # are announced with an estimate before they start and show progress: a tqdm bar on a terminal, else a line on
    # stderr every progress_log_s seconds.
    progress_log_s: float = within(5.0, 0.0, 10_000.0)
    # The estimates: a sequence takes synth_setup_s + frames x synth_frame_s / workers to generate, a frame
    # segment_frame_s to segment (docs/benchmarks.md: 13.1 frames/s segmented by two workers in the study; "Generator":
    # 14.8 frames/s generated by two busy workers in the study's sequence phase).
    synth_setup_s: float = within(5.0, 0.0, 10_000.0)
    synth_frame_s: float = within(0.11, 0.0, 1000.0)
    # A twin's frame (d2slam.synth.twin: sub-frames over the exposure and the rolling shutters) takes
    # synth_twin_frame_s instead (1.0 frames/s measured on fr1/rpy's first 200 frames, one worker, a busy machine).
    synth_twin_frame_s: float = within(1.0, 0.0, 1000.0)
    # A composite's frame (d2slam.synth.compositing: the people's sub-frames over the exposure, z-tested, on the real
    # images) takes synth_composite_frame_s on average (fr1/rpy's first 120 frames, people in 40 % of them, one
    # worker, a busy machine: 1.05 s).
    synth_composite_frame_s: float = within(1.0, 0.0, 1000.0)
    segment_frame_s: float = within(0.15, 0.0, 1000.0)
    # The caches' cheap checks (the mask cache's image digest, a cached folder's manifest) trust a file's size and
    # modification time only when it was last modified at least this long before they were recorded: a change made
    # within a file system's timestamp resolution (FAT: 2 s; ext4, tmpfs: 1 ns) could keep the recorded time.
    cache_mtime_window_s: float = within(2.0, 0.0, 3600.0)
    # Depth-scale check of `d2slam run` against the ground truth's camera motion (d2slam.data.depth_scale): among
    # depth_candidate_frames frames spread over the sequence, up to depth_pairs pairs (one per first frame, spread over
    # the sequence) whose ground-truth poses are depth_min_baseline_m to depth_max_baseline_m apart and turn by at most
    # depth_max_rotation_deg (the views overlap); per frame depth_orb_features ORB keypoints with depth, cross-checked
    # Hamming matches within depth_max_hamming; the relative pose by a 3-D/3-D RANSAC (depth_ransac_iterations
    # hypotheses of 3 matches, seeded with depth_ransac_seed; inlier when the residual is within depth_inlier_rel of
    # the point's depth, which does not depend on the scale) with at least depth_min_inliers inliers. The depth is off
    # when the median ratio of the estimated to the true camera translation is beyond depth_ratio_tolerance either way
    # (a factor 5, e.g. millimetres read with TUM's 5000, gives 0.2 or 5). Without ground truth or camera motion,
    # DataConfig's median-depth window decides, and the depth_far_percentile of the valid depth must reach
    # depth_far_min_m (a room's far side; millimetres read as 1/5000 m bring it within a metre).
    depth_candidate_frames: int = within(300, 2, 1_000_000)
    depth_pairs: int = within(5, 1, 1000)
    depth_min_baseline_m: float = within(0.05, 0.0, 100.0)
    depth_max_baseline_m: float = within(0.5, 0.0, 100.0, lo_open=True)
    depth_max_rotation_deg: float = within(20.0, 0.0, 180.0)
    depth_orb_features: int = within(600, 1, 100_000, why=ORB_FEATURES_WHY)
    depth_max_hamming: int = within(50, 0, 256)
    depth_ransac_iterations: int = within(200, 1, 1_000_000)
    depth_ransac_seed: int = seed(0)
    depth_inlier_rel: float = within(0.02, 0.0, 1.0, lo_open=True)
    depth_min_inliers: int = within(30, 3, 100_000)
    depth_ratio_tolerance: float = within(2.0, 1.0, 1000.0, lo_open=True)
    depth_far_percentile: float = within(95.0, 0.0, 100.0)
    depth_far_min_m: float = within(1.0, 0.0, 100.0)
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


def _type_name(tp) -> str:
    """``float``, ``tuple[float, float]``, ``one of 'lm', 'g2o'``: a field's type as the error message says it."""
    if typing.get_origin(tp) is Literal:
        return "one of " + ", ".join(repr(a) for a in typing.get_args(tp))
    if typing.get_origin(tp) is tuple:
        args = typing.get_args(tp)
        inner = f"{_type_name(args[0])}, ..." if len(args) == 2 and args[1] is Ellipsis else \
            ", ".join(_type_name(a) for a in args)
        return f"tuple[{inner}]"
    return getattr(tp, "__name__", str(tp))


def _typed(value, tp, where: str):
    """``value`` as a field of type ``tp`` holds it (an int for a float, a list for a tuple, recursively; numpy
    numbers as Python's), or a one-line ``TypeError`` naming the field (``where``), the type expected and the value
    given. A bool is not a number (YAML's ``yes`` would otherwise be 1). Returns ``value`` itself when it is already
    what the field holds."""
    origin = typing.get_origin(tp)
    ok = True
    if tp is bool:
        ok = isinstance(value, bool)
    elif tp is int:
        ok = isinstance(value, numbers.Integral) and not isinstance(value, bool)
        value = int(value) if ok and type(value) is not int else value
    elif tp is float:
        ok = isinstance(value, numbers.Real) and not isinstance(value, bool)
        value = float(value) if ok and type(value) is not float else value
    elif tp is str:
        ok = isinstance(value, str)
    elif origin is Literal:
        ok = any(value == a and type(value) is type(a) for a in typing.get_args(tp))
    elif origin is tuple:
        args = typing.get_args(tp)
        ok = isinstance(value, (list, tuple)) and (
            (len(args) == 2 and args[1] is Ellipsis) or len(value) == len(args))
        if ok:
            items = args[:1] * len(value) if len(args) == 2 and args[1] is Ellipsis else args
            typed = tuple(_typed(v, t, f"{where}[{i}]") for i, (v, t) in enumerate(zip(value, items)))
            return value if isinstance(value, tuple) and all(a is b for a, b in zip(typed, value)) else typed
    if not ok:
        raise TypeError(f"{where} must be {_type_name(tp)}, got {value!r} ({type(value).__name__})")
    return value


def _section(section_cls, data: dict, name: str):
    """One config dataclass from a (possibly partial) dict: nested sections built recursively; every value is
    checked against its field's type and range by the section itself (:class:`_Checked`)."""
    known = {g.name: g for g in dataclasses.fields(section_cls)}
    unknown = set(data) - set(known)
    if unknown:
        raise ValueError(f"unknown {name} config keys: {sorted(unknown)}")
    hints = _hints(section_cls)
    kwargs = {}
    for key, value in data.items():
        tp = hints[key]
        if dataclasses.is_dataclass(tp):
            if not isinstance(value, dict):
                raise TypeError(f"{name}.{key} must be a section of fields ({tp.__name__}), got {value!r}")
            value = _section(tp, value, f"{name}.{key}")
        kwargs[key] = value
    return section_cls(**kwargs)  # types and ranges: checked by the section (_Checked)


@dataclass(frozen=True)
class EvalConfig(_Checked):
    """How a run is judged: the share of its frames it tracked (``d2slam.record``) and its loops against the ground
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
class OnlineConfig(_Checked):
    """An online run (``d2slam run --online``, ``d2slam.online``): frames replayed at the sensor's rate, the
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
    # onnxruntime's intra-op threads of the segmenter's thread (the tracker has the other core).
    segmenter_threads: int = within(1, 1, 64)


@dataclass(frozen=True)
class Config(_Checked):
    # The engine initialises on a frame with init_min_keypoints keypoints with depth: fewer features never track.
    _RULES = (rule(("orb.n_features", "engine.init_min_keypoints"), lambda n, k: n >= k,
                   "{0} must be at least {1}: the engine could never initialise"),)

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
                kwargs[f.name] = _section(_hints(cls)[f.name], data[f.name], f.name)
        unknown = set(data) - {f.name for f in dataclasses.fields(cls)}
        if unknown:
            raise ValueError(f"unknown config sections: {sorted(unknown)}")
        return cls(**kwargs)

    def hash(self) -> str:
        blob = json.dumps(self.to_dict(), sort_keys=True, default=list).encode()
        return hashlib.sha256(blob).hexdigest()[:12]


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
    from pathlib import Path

    import yaml

    from d2slam.errors import D2SlamError

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
