"""Benchmarks that print figures (``d2slam bench TOPIC``). One module per topic, each defining
``DESCRIPTION``, ``add_arguments(parser)`` and ``run(args) -> int | None``. Speed and accuracy targets are checked
here, by commands that print numbers, never by timed unit tests."""

from __future__ import annotations

import importlib
import pkgutil


def topics() -> list[str]:
    return sorted(m.name for m in pkgutil.iter_modules(__path__) if not m.name.startswith("_"))


def load(topic: str):
    return importlib.import_module(f"{__name__}.{topic}")
