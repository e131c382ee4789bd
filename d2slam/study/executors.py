"""Run a list of tasks on one of three executors, with a tqdm bar, results returned in the input order.

* ``serial``: in this process (``jobs=1``);
* ``joblib``: ``jobs`` loky worker processes (``jobs > 1``), each with single-threaded BLAS/OpenMP
  (``inner_max_num_threads=1``) and OpenCV on one thread (set per run);
* ``dask``: a ``dask.distributed`` cluster (``scheduler="tcp://HOST:PORT"``, or a ``Client`` / ``LocalCluster``
  given directly). Start its workers with ``OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1`` and ``--nthreads 1``
  (one run per core; the numbers do not depend on it, the speed does).

The function must be importable (a module-level function) and its arguments picklable. Results are placed by
index, so the output order never depends on which worker finished first.
"""

from __future__ import annotations

from typing import Callable, Sequence

from tqdm import tqdm

from d2slam.errors import D2SlamError


def executor_name(jobs: int = 1, scheduler=None) -> str:
    if scheduler is not None:
        return "dask"
    return "serial" if int(jobs) <= 1 else "joblib"


def map_ordered(fn: Callable, items: Sequence, args: tuple = (), jobs: int = 1, scheduler=None,
                desc: str = "study", progress: bool | None = None,
                on_result: Callable[[int, object], None] | None = None) -> list:
    """``[fn(item, *args) for item in items]`` on the chosen executor (see module docstring). ``on_result(i, result)``
    is called in this process as each result arrives (completion order), e.g. to save it at once."""
    items = list(items)
    if not items:
        return []
    bar = tqdm(total=len(items), desc=desc, unit="run", disable=None if progress is None else not progress)
    try:
        name = executor_name(jobs, scheduler)
        if name == "serial":
            out = []
            for i, it in enumerate(items):
                out.append(fn(it, *args))
                if on_result is not None:
                    on_result(i, out[-1])
                bar.update(1)
            return out
        if name == "joblib":
            return _joblib(fn, items, args, int(jobs), bar, on_result)
        return _dask(fn, items, args, scheduler, bar, on_result)
    finally:
        bar.close()


def _joblib(fn, items, args, jobs, bar, on_result=None) -> list:
    from joblib import Parallel, delayed, parallel_config

    out = [None] * len(items)
    with parallel_config(backend="loky", n_jobs=jobs, inner_max_num_threads=1):
        gen = Parallel(return_as="generator_unordered")(delayed(_indexed)(i, fn, it, args)
                                                          for i, it in enumerate(items))
        for i, res in gen:
            out[i] = res
            if on_result is not None:
                on_result(i, res)
            bar.update(1)
    return out


def _indexed(i, fn, item, args):
    return i, fn(item, *args)


def _dask(fn, items, args, scheduler, bar, on_result=None) -> list:
    try:
        from distributed import Client, as_completed
    except ImportError as exc:  # pragma: no cover - dask/distributed are in environment.txt
        raise D2SlamError(f"--scheduler needs dask.distributed: {exc}") from None
    own = False
    if isinstance(scheduler, Client):
        client = scheduler
    elif hasattr(scheduler, "scheduler_address"):  # a LocalCluster / any cluster object
        client, own = Client(scheduler), True
    else:
        address = str(scheduler)
        if "://" not in address:
            raise D2SlamError(f"--scheduler must be an address like tcp://HOST:PORT, got {address!r}")
        try:
            client, own = Client(address, timeout="10s"), True
        except (OSError, TimeoutError) as exc:
            raise D2SlamError(f"cannot reach the Dask scheduler at {address}: {exc}") from None
    try:
        futures = [client.submit(_indexed, i, fn, it, args, pure=False) for i, it in enumerate(items)]
        out = [None] * len(items)
        for fut in as_completed(futures):
            i, res = fut.result()
            out[i] = res
            if on_result is not None:
                on_result(i, res)
            bar.update(1)
        return out
    finally:
        if own:
            client.close()
