"""``results/manifest.json``: what produced a study's numbers (git commit, config hash, grid, generator version,
package versions, machine)."""

from __future__ import annotations

import os
import platform
import subprocess
import sys

import d2slam
from d2slam.paths import REPO_ROOT
from d2slam.study.keys import code_info, package_versions

PACKAGES = ("numpy", "scipy", "opencv-python-headless", "onnxruntime", "gtsam", "g2opy", "evo", "pyorbslam3",
            "pandas", "matplotlib", "joblib", "dask", "distributed", "tqdm")
REQUIRED = ("git", "config_hash", "generator_version", "grid", "packages", "machine", "d2slam_version")


def git_info(root=REPO_ROOT) -> dict:
    """``{"commit", "dirty"}`` of the checkout (``None`` outside a git checkout)."""
    def git(*args):
        return subprocess.run(["git", "-C", str(root), *args], capture_output=True, text=True, timeout=10)

    try:
        head = git("rev-parse", "HEAD")
        if head.returncode != 0:
            return {"commit": None, "dirty": None}
        status = git("status", "--porcelain", "--untracked-files=no", "--", "d2slam")
        return {"commit": head.stdout.strip(), "dirty": bool(status.stdout.strip())}
    except (OSError, subprocess.SubprocessError):
        return {"commit": None, "dirty": None}


def cpu_model() -> str:
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.lower().startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def machine_info() -> dict:
    return {"cpu": cpu_model(), "cores": os.cpu_count(), "python": sys.version.split()[0],
            "implementation": platform.python_implementation(), "platform": platform.platform(),
            "threads": {k: os.environ.get(k) for k in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")}}


def build_manifest(config, grid: dict, executor: dict, generator_version: str, timing: dict | None = None,
                   git: dict | None = None, code: dict | None = None) -> dict:
    """The study's manifest. ``git`` and ``code`` are taken when the study starts (``run_study``): a commit made
    while it runs must not be recorded as the code that ran. Default: now."""

    return {"d2slam_version": d2slam.__version__, "git": git if git is not None else git_info(),
            "code": code if code is not None else code_info(), "config_hash": config.hash(),
            "generator_version": generator_version, "grid": grid, "executor": executor,
            "packages": package_versions(PACKAGES), "machine": machine_info(), "timing": timing or {}}
