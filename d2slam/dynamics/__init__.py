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
  run-method registry (``d2slam.run.methods``) builds under the study's method names
"""

from __future__ import annotations
