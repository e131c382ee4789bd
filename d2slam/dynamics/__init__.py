"""The paper's modules as pure vectorised functions of arrays (one file per equation group) and the classifier
behind the engine's keypoint-filter hook.

- ``depth``: s(z), beta(z) (eq 2), alpha(z) (eq 5), delta(z) (eq 9), gamma(z) (eq 10), robust keypoint depth
- ``semantic``: eq 1-2, signed distance to mask edges, P_S, uncertainty zone
- ``geometric``: eq 4-6, RANSAC fundamental matrix, epipolar error, P_g
- ``fusion``: eq 7 (four cases) and eq 8 (Bayesian filter)
- ``interaction``: eq 9-10, the Object Interaction Module
- ``classifier``: ``D2SlamFilter`` / ``get_filter(method, config)`` with the ablation modes
"""

from d2slam.dynamics.classifier import METHODS, MODES, D2SlamFilter, FrameDiagnostics, get_filter  # noqa: F401
