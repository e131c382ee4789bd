"""The paper's modules as pure vectorised functions of arrays (one file per equation group) and the classifier
behind the engine's keypoint-filter hook.

- ``depth``: s(z), beta(z) (eq 2), alpha(z) (eq 5), delta(z) (eq 9), gamma(z) (eq 10), robust keypoint depth
- ``semantic``: eq 1-2, signed distance to mask edges, P_S, uncertainty zone
- ``geometric``: eq 4-6, RANSAC fundamental matrix, epipolar error, P_g
- ``fusion``: eq 7 (four cases) and eq 8 (Bayesian filter); ours: the edge band of ``d2slam-flow`` (``edge_band``)
- ``interaction``: eq 9-10, the Object Interaction Module
- ``flow``: ours, sub-pixel correspondences for eq 4-6 by LK flow (the ``d2slam-flow`` mode)
- ``classifier``: ``D2SlamFilter`` / ``get_filter(method, config)`` with the ablation modes; ``register_methods``
  puts them in the run-method registry (``d2slam.methods``)

The classifier (numpy, scipy, OpenCV) is imported on first use of ``D2SlamFilter``, ``FrameDiagnostics`` or
``get_filter`` (PEP 562): the command line lists the method names without paying for those imports (measured:
docs/deviations.md, "Measurements behind implementation choices").
"""

from __future__ import annotations

# The ablation modes (see classifier.py) with the help text of ``d2slam run --method``; ``needs_masks`` per mode.
MODE_HELP = {
    "d2slam": "full D2SLAM: semantic + geometric + Bayesian fusion + object interaction (eq 1-10)",
    "d2slam-flow": ("ours: d2slam with sub-pixel LK flow correspondences for eq 5 and the edge band "
                    "(DynamicsConfig.flow, flow_edge_band)"),
    "no-depth": "D2SLAM with every depth-adaptive quantity at its midpoint and no OIM depth test",
    "no-oim": "D2SLAM without the object interaction module (eq 9-10)",
    "no-bayes": "D2SLAM with the eq 7 probability used directly (no eq 8 filter)",
    "semantic": "masks only, DynaSLAM-like: keypoints inside a person mask are dynamic",
    "geometric": "epipolar check only (fixed threshold), no masks, no filter",
}
MODES = tuple(MODE_HELP)
METHODS = MODES + ("none",)
NEEDS_MASKS = {mode: mode != "geometric" for mode in MODES}

_LAZY = ("D2SlamFilter", "FrameDiagnostics", "get_filter")


def register_methods(register) -> None:
    """Register the six modes with the run-method registry's ``register(name, factory, needs_masks, help)``
    (``d2slam.methods``; ``none`` stays the engine's). Each factory builds ``get_filter(mode, config)``."""
    for mode in MODES:
        register(mode, _Factory(mode), needs_masks=NEEDS_MASKS[mode], help=MODE_HELP[mode])


class _Factory:
    """config -> D2SlamFilter of one mode (imports the classifier only when a filter is built)."""

    def __init__(self, mode: str):
        self.mode = mode

    def __call__(self, config=None):
        from d2slam.dynamics.classifier import get_filter

        return get_filter(self.mode, config)

    def __repr__(self) -> str:
        return f"dynamics filter factory {self.mode!r}"


def __getattr__(name: str):
    if name in _LAZY:
        from d2slam.dynamics import classifier

        return getattr(classifier, name)
    raise AttributeError(f"module 'd2slam.dynamics' has no attribute {name!r}")
