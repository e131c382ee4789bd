"""The real ORB-SLAM3 baseline (pyorbslam3) and the DBoW2 vocabulary it needs."""

from __future__ import annotations

import os
from pathlib import Path

import d2slam


def child_env() -> dict:
    """The environment of a ``python -m d2slam...`` child process: it imports this d2slam, whatever folder it starts
    in (``PYTHONSAFEPATH``: no working folder first on ``sys.path``, where another d2slam checkout may sit; this
    package's parent folder first on ``PYTHONPATH``)."""
    env = dict(os.environ)
    root = str(Path(d2slam.__file__).resolve().parent.parent)
    env["PYTHONPATH"] = root + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    env["PYTHONSAFEPATH"] = "1"
    return env
