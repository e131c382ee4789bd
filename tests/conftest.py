"""Shared fixtures."""

from __future__ import annotations

import pytest


@pytest.fixture
def assets_kept(monkeypatch):
    """The segmentation models and the real TUM frames stay where they were found when a test moves
    ``$D2SLAM_CACHE``: a clone without ../shared keeps them in the cache (``d2slam assets fetch``), which the test's
    own cache would hide (the segmenter, and the vocabulary built from the real frames, need them)."""
    from d2slam.assets import INT8_MODEL, asset_path

    model = asset_path(INT8_MODEL)
    monkeypatch.setenv("D2SLAM_SHARED", str(model.parents[1]))


class FaultWorld:
    """A cache of its own (``cache``) holding a short synthetic sequence (``seq``: sitting_static, seed 3, 6 frames,
    in the study's sequence cache) and the project's vocabulary, built in this process; ``run`` starts ``d2slam`` (or
    a fault hook around it: ``tests/fault_hook.py``) in a child process on that cache, ``env`` sets it in this one."""

    SCENARIO, SEED, FRAMES = "sitting_static", 3, 6

    def __init__(self, root, shared):
        import os
        import sys
        from pathlib import Path

        self.root, self.cache, self.shared = Path(root), Path(root) / "cache", str(shared)
        self.python = sys.executable
        self.repo = Path(__file__).resolve().parent.parent
        self.child_env = {**os.environ, "D2SLAM_CACHE": str(self.cache), "D2SLAM_SHARED": self.shared,
                          "PYTHONPATH": os.pathsep.join(filter(None, [str(self.repo), os.environ.get("PYTHONPATH")])),
                          "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1",
                          "PYTHONHASHSEED": "0"}
        self.seq = None

    def env(self, monkeypatch, cache=None) -> None:
        """This process reads and writes ``cache`` (default the world's) with the shared assets visible."""
        monkeypatch.setenv("D2SLAM_CACHE", str(cache or self.cache))
        monkeypatch.setenv("D2SLAM_SHARED", self.shared)

    def start(self, *args, hook=None, cache=None, **popen):
        """``d2slam ARGS`` started in a child process (``hook``: (target, n, action[, match]) of
        tests/fault_hook.py; ``args`` may start with ``--python`` CODE); returns the Popen (text pipes)."""
        import subprocess

        env = dict(self.child_env, **({"D2SLAM_CACHE": str(cache)} if cache else {}))
        if hook:
            head = [self.python, str(self.repo / "tests" / "fault_hook.py"), *map(str, hook), "--"]
        elif args[:1] == ("--python",):
            head, args = [self.python, "-c"], args[1:]
        else:
            head = [self.python, "-m", "d2slam.cli"]
        return subprocess.Popen(head + [str(a) for a in args], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                text=True, env=env, **popen)

    @staticmethod
    def wait(proc, timeout=300):
        """The CompletedProcess of a child :meth:`start` began."""
        import subprocess

        out, err = proc.communicate(timeout=timeout)
        return subprocess.CompletedProcess(proc.args, proc.returncode, out, err)

    def run(self, *args, timeout=300, **kwargs):
        """:meth:`start`, then :meth:`wait`."""
        return self.wait(self.start(*args, **kwargs), timeout)


@pytest.fixture(scope="session")
def fault_world(tmp_path_factory):
    """The world of the fault-injection tests (tests/test_faults_*.py): see :class:`FaultWorld`."""
    import shutil

    from d2slam.assets import INT8_MODEL, asset_path
    from d2slam.paths import cache_root
    from d2slam.synth.version import generator_version

    world = FaultWorld(tmp_path_factory.mktemp("faults"), asset_path(INT8_MODEL).parents[1])
    # The user's rendered training frames spare rendering them (the same bytes on every CPU tried). The vocabulary
    # itself is built here, not copied: the tests rebuild it and compare with the world's, and a build on another
    # CPU's SIMD paths differs (OpenCV's ORB gives 3 of its 85,000 descriptors one other bit with x86-64-v2's paths
    # forced, and the k-majority tree grown from them differs in most of its nodes).
    frames = cache_root() / "vocab" / "train" / generator_version()
    if frames.is_dir():
        shutil.copytree(frames, world.cache / "vocab" / "train" / frames.name,
                        ignore=shutil.ignore_patterns("*.lock", "*.tmp-*", "*.part"))
    with pytest.MonkeyPatch.context() as mp:
        world.env(mp)
        from d2slam.baselines.vocab import build_vocabulary
        from d2slam.slam.orb_vocabulary import load_vocabulary
        from d2slam.study.sequences import ensure_sequence

        build_vocabulary(progress=False)
        load_vocabulary()  # its bag of words derived for the engine, as a first run would
        world.seq = ensure_sequence(world.SCENARIO, world.SEED, world.FRAMES, progress=False)
    return world
