"""Where things live: the read-only shared folder (models, real TUM frames) and the cache (outside git)."""

from __future__ import annotations

import os
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parent.parent


def shared_dir() -> Path:
    """``$D2SLAM_SHARED`` or ``../shared`` beside the checkout (read-only; never copied into the repo)."""
    env = os.environ.get("D2SLAM_SHARED")
    return Path(env).expanduser().resolve() if env else (REPO_ROOT.parent / "shared").resolve()


def cache_dir(*parts: str) -> Path:
    """``$D2SLAM_CACHE`` or ``~/.cache/d2slam``, created on demand (derived files: sequences, masks, vocabularies)."""
    env = os.environ.get("D2SLAM_CACHE")
    root = Path(env).expanduser() if env else Path.home() / ".cache" / "d2slam"
    path = root.joinpath(*parts)
    path.mkdir(parents=True, exist_ok=True)
    return path


def checkout_root() -> Path | None:
    """The d2slam checkout to work in (``d2slam docs``): the current folder when it is one, else the repository the
    package is installed from (an editable install); None outside any. A checkout holds ``pyproject.toml``, the
    ``d2slam`` package, ``docs/`` and ``results/``."""
    for root in (Path.cwd(), REPO_ROOT):
        if all((root / p).exists() for p in ("pyproject.toml", "d2slam/__init__.py", "docs", "results")):
            return root.resolve()
    return None
