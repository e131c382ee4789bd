"""How a config section declares its fields and checks them: the machinery every part's config uses.

A section is a frozen dataclass deriving from :class:`Checked`. Every field declares its valid range beside its
default (:func:`within`, :func:`one_of`, :func:`flag`, :func:`text`, :func:`seed`; a nested section: :func:`section`),
and a section lists the orderings between its fields (``_RULES``: a minimum below its maximum, ...; :func:`below`,
:func:`rule`). Both are checked whenever a section is built, from a file, a dict (:func:`build_section`) or Python
(direct construction, ``dataclasses.replace``): a value of the wrong type or out of its range is one
:class:`ConfigError` line naming ``section.field``, the value and the range (``dynamics.z_far = nan is out of range: a
finite number in (0, 20]``). Ints given for a float field are stored as floats and lists for a tuple field as tuples,
so that equal configs hash equal however they were built. A section's name in messages is the one the composed config
gives it (:func:`name_sections`; ``d2slam.config`` names its own), else its class name.
"""

from __future__ import annotations

import dataclasses
import importlib
import math
import numbers
import typing
from dataclasses import dataclass, field
from typing import ClassVar, Literal

from d2slam.errors import D2SlamError


# --------------------------------------------------------------------------------------------------
class ConfigError(D2SlamError, ValueError, TypeError):
    """A config value of the wrong type or out of its range (one line naming ``section.field``, the value and the
    range). A ``D2SlamError`` (the command line prints it) and a ``ValueError`` / ``TypeError`` (what the config
    readers catch to name the file)."""


INT_MAX = 2**31 - 1  # seeds and counts that reach C++ (OpenCV, ORB-SLAM3) as a 32-bit int


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
_NAMES: dict[type, str] = {}  # section class -> its name in a config file (name_sections)


def _hints(cls) -> dict:
    if cls not in _HINTS:
        _HINTS[cls] = typing.get_type_hints(cls)
    return _HINTS[cls]


def name_sections(root, prefix: str = "") -> None:
    """Record the name of each section of ``root`` (a composed config class) as a config file writes it
    (``dynamics``, ``synth.body``; ``prefix`` before them), for the messages of :class:`Checked`."""
    if prefix:
        _NAMES[root] = prefix.rstrip(".")
    for f in dataclasses.fields(root):
        tp = _hints(root)[f.name]
        if dataclasses.is_dataclass(tp):
            name_sections(tp, prefix + f.name + ".")


def _where(obj, name: str) -> str:
    sec = _NAMES.get(type(obj))
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


class Checked:
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


def build_section(section_cls, data: dict, name: str):
    """One config dataclass from a (possibly partial) dict: nested sections built recursively; every value is
    checked against its field's type and range by the section itself (:class:`Checked`)."""
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
            value = build_section(tp, value, f"{name}.{key}")
        kwargs[key] = value
    return section_cls(**kwargs)  # types and ranges: checked by the section (Checked)



# A composed config (``d2slam.config.Config``, above the parts in the layers): a part reads its own sections of one
# without importing it.
AnyConfig = typing.Any


def part_of(config, name: str, cls):
    """The ``name`` section (a ``cls``) of a composed config, ``config`` itself when it is a ``cls``, or the defaults
    when it is None."""
    if config is None:
        return cls()
    if isinstance(config, cls):
        return config
    sec = getattr(config, name, None)
    if isinstance(sec, cls):
        return sec
    raise TypeError(f"expected a config with a {name} section or a {cls.__name__}, got {type(config).__name__}")


def overridden(obj, changes: dict):
    """``obj`` (a section) with the fields of ``changes`` replaced (``{field: value}``; a nested section's fields as
    a dict of their own, ``{"tracking": {"init_min_keypoints": 200}}``: the others keep their values). Checked as any
    section is. An unknown field is a ``ValueError`` naming it."""
    if not isinstance(changes, dict):
        raise ValueError(f"expected fields of {type(obj).__name__} as a mapping, got {changes!r}")
    known = {f.name: f for f in dataclasses.fields(obj)}
    new = {}
    for key, value in changes.items():
        if key not in known:
            raise ValueError(f"unknown field {_where(obj, key)}")
        if known[key].metadata.get("section") and isinstance(value, dict):
            value = overridden(getattr(obj, key), value)
        new[key] = value
    return dataclasses.replace(obj, **new)


def flat_fields(obj, prefix: str = "") -> dict:
    """{dotted name: value} of every field of a section and of its nested sections (``ours.alpha_at_scale``)."""
    out = {}
    for f in dataclasses.fields(obj):
        value = getattr(obj, f.name)
        if dataclasses.is_dataclass(value):
            out.update(flat_fields(value, f"{prefix}{f.name}."))
        else:
            out[f"{prefix}{f.name}"] = value
    return out
