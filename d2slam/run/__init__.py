"""The run path: one method run on one sequence, typed from end to end.

* ``methods``: the registry of run methods (``d2slam run --method NAME``);
* ``sequence``: ``run_sequence``, the per-sequence loop (prefetch, stored features, per-stage timings);
* ``runner``: ``run_method``, the one place where ``d2slam run`` and the study run a method of our engine, and
  ``run_config`` (the config as one run uses it: its seed, loop closing, ThDepth);
* ``record``: ``RunRecord`` (what every run gives) with each method's own account of a run (``EngineRun``,
  ``Orbslam3Run``);
* ``orbslam3_runs``: the real ORB-SLAM3's runs as records;
* ``metrics``: the run JSON of ``d2slam run --metrics-json``, written from a ``RunRecord`` in one place;
* ``observe``: the engine's inputs logged frame by frame (``engine_log``), for the sensor-realism measurements;
* ``warmup``: the compiled kernels compiled or loaded before the first run.
"""
