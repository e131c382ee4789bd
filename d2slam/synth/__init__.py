"""The synthetic TUM-like dynamic benchmark generator (docs/design.md#the-synthetic-benchmark).

``generate(scenario, out, frames, seed, static_twin)`` writes a sequence in the TUM RGB-D layout plus
``mask_gt/``, ``mask_sim/`` and ``scene.json`` (format in CONTRIBUTING.md). Modules: ``scene`` (office room,
people, moved objects, fr3-like camera paths), ``bodies`` (articulated MakeHuman bodies: gait, clothes), ``gl``
(pyrender offscreen OpenGL renderer), ``world`` (the scene as meshes for it), ``render`` (textured quads as arrays,
and a small OpenCV rasteriser of them), ``textures``, ``sensor`` (Kinect-like depth noise, holes, RGB blur and
noise), ``segsim`` (simulated segmenter), ``generate``; ``twin`` (the synthetic twin of a real recording: its
ground truth, times, camera and a sensor calibrated against it, ``SynthConfig.twin``).
"""

from d2slam.synth.generate import FORMAT, generate, render_frame  # noqa: F401
from d2slam.synth.scene import SCENARIOS, Scene  # noqa: F401
