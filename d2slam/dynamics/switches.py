"""Which parts of D2SLAM's classifier run (``d2slam.dynamics.classifier.D2SlamFilter``): the study's ablations are
the full method with one switch off (``d2slam.run.methods`` builds them). Plain data: the command line lists the methods
without loading the classifier."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Switches:
    depth: bool = True  # the depth-adaptive quantities (eq 2, 5, 9, 10); off: each at the midpoint of its range
    bayes: bool = True  # eq 8's temporal filter; off: eq 7's probability is the belief
    oim: bool = True  # the Object Interaction Module (eq 9-10)
    flow: bool = False  # ours: sub-pixel LK-flow correspondences for eq 5 and the edge band (d2slam.dynamics.flow)
