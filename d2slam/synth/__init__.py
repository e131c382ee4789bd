"""The synthetic TUM-like dynamic benchmark generator (DESIGN.md section 3).

``generate(scenario, out, frames, seed, static_twin)`` writes a sequence in the TUM RGB-D layout plus
``mask_gt/``, ``mask_sim/`` and ``scene.json`` (format in CONTRIBUTING.md). Modules: ``scene`` (room, people,
moved objects, fr3-like camera paths), ``render`` (z-buffered textured quads with OpenCV), ``textures``,
``sensor`` (Kinect-like depth noise, holes, RGB blur and noise), ``segsim`` (simulated segmenter), ``generate``.
"""

from d2slam.synth.generate import FORMAT, generate, render_frame  # noqa: F401
from d2slam.synth.scene import SCENARIOS, Scene  # noqa: F401
