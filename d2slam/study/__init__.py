"""The reproducible study (``d2slam study``): the grid of scenarios x methods x seeds (and static twins) run on a
local or Dask executor, evaluated with evo, summarised in the paper's table layout.

- ``grid``: :class:`RunSpec`, :func:`expand_grid` (deterministic order), scenario labels, defaults
- ``sequences``: the synthetic-sequence cache keyed by scenario / seed / frames / twin / generator version
- ``runner``: :func:`execute_run` (one cell; never raises: failures are rows)
- ``executors``: :func:`map_ordered` (serial, joblib processes, dask.distributed)
- ``tables``: CSV schema, medians and spreads, improvement %, Markdown tables, static-twin ratios
- ``plots``, ``manifest``, ``core`` (:func:`run_study`, :func:`rebuild_tables`)
"""

from d2slam.study.core import StudyResult, rebuild_tables, run_study  # noqa: F401
from d2slam.study.grid import LABELS, SCENARIOS, RunSpec, expand_grid  # noqa: F401
from d2slam.study.tables import improvement, summarise, tables_markdown  # noqa: F401
