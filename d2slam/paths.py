"""Where things live: the read-only shared folder (models, real TUM frames) and the cache (outside git)."""

from __future__ import annotations

import os
from pathlib import Path

from d2slam.errors import D2SlamError

REPO_ROOT = Path(__file__).resolve().parent.parent


def shared_dir() -> Path:
    """``$D2SLAM_SHARED`` or ``../shared`` beside the checkout (read-only; never copied into the repo)."""
    env = os.environ.get("D2SLAM_SHARED")
    return Path(env).expanduser().resolve() if env else (REPO_ROOT.parent / "shared").resolve()


def cache_root() -> Path:
    """``$D2SLAM_CACHE`` or ``~/.cache/d2slam`` (not created)."""
    env = os.environ.get("D2SLAM_CACHE")
    return Path(env).expanduser() if env else Path.home() / ".cache" / "d2slam"


def cache_dir(*parts: str) -> Path:
    """``$D2SLAM_CACHE`` or ``~/.cache/d2slam``, created on demand (derived files: sequences, masks, vocabularies).
    A cache that cannot be created (a file in the way, a read-only parent) is a one-line ``D2SlamError``."""
    path = cache_root().joinpath(*parts)
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise D2SlamError(f"cannot create the cache folder ({exc.strerror or exc}); set $D2SLAM_CACHE to a writable "
                          "folder", path=path) from None
    return path


#: The folders of the cache that d2slam manages (what it reads back and rebuilds), with what they hold: no command
#: writes a user's output there (``d2slam.outputs.check_outputs``). Other folders of the cache (``demo``, ``bench``)
#: hold outputs.
MANAGED_CACHE = (("masks", "the mask cache"), ("vocab", "the vocabulary cache"), ("assets", "the asset cache"),
                 ("study/sequences", "the sequence cache"), ("study/features", "the feature cache"))


def managed_cache_dirs() -> list[tuple[Path, str]]:
    """``(folder, what it is)`` of :data:`MANAGED_CACHE` under the cache (which need not exist)."""
    return [(cache_root() / rel, what) for rel, what in MANAGED_CACHE]


def checkout_root() -> Path | None:
    """The d2slam checkout to work in (``d2slam docs``): the current folder when it is one, else the repository the
    package is installed from (an editable install); None outside any. A checkout holds ``pyproject.toml``, the
    ``d2slam`` package, ``docs/`` and ``results/``."""
    for root in (Path.cwd(), REPO_ROOT):
        if all((root / p).exists() for p in ("pyproject.toml", "d2slam/__init__.py", "docs", "results")):
            return root.resolve()
    return None
