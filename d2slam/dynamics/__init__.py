"""The paper's modules as pure vectorised functions of arrays (one file per equation group) and the classifier
behind the engine's keypoint-filter hook.

- ``depth``: s(z), beta(z) (eq 2), alpha(z) (eq 5), delta(z) (eq 9), gamma(z) (eq 10)
- ``semantic``: eq 1-2, signed distance to mask edges, P_S, uncertainty zone
- ``geometric``: eq 4-6, RANSAC fundamental matrix, epipolar error, P_g
- ``fusion``: eq 7 (four cases) and eq 8 (Bayesian filter); ours: the edge band of ``d2slam-flow`` (``edge_band``)
- ``interaction``: eq 9-10, the Object Interaction Module
- ``flow``: ours, sub-pixel correspondences for eq 4-6 by LK flow (the ``d2slam-flow`` method)
- ``switches``: the ablations' switches (depth, Bayes, OIM, flow)
- ``classifier``: ``D2SlamFilter`` (with its switches), ``SemanticFilter`` and ``EpipolarFilter``, which the
  run-method registry (``d2slam.methods``) builds under the study's method names

The classifier (numpy, scipy, OpenCV) is imported on first use of one of its names here (PEP 562): the command
line lists the method names without paying for those imports (measured: docs/deviations.md, "Measurements behind
implementation choices").
"""

from __future__ import annotations

_LAZY = ("D2SlamFilter", "SemanticFilter", "EpipolarFilter", "FrameDiagnostics")


def __getattr__(name: str):
    if name in _LAZY:
        from d2slam.dynamics import classifier

        return getattr(classifier, name)
    raise AttributeError(f"module 'd2slam.dynamics' has no attribute {name!r}")
