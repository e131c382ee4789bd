"""Run a list of tasks on one of three executors, with progress on stderr, results returned in the input order.

* ``serial``: in this process (``jobs=1``);
* ``joblib``: ``jobs`` worker processes of joblib's loky (``jobs > 1``), each with single-threaded BLAS/OpenMP
  and OpenCV on one thread (set per run). One pool per call, shut down when the call returns: a worker lives for
  the whole call and keeps what it loaded (its first task's size is the reference of loky's leak check, so a
  worker is not recycled, with a warning, for holding the segmenter loaded by a later task). The workers ignore
  SIGINT: a Ctrl-C reaches this process only, which kills the pool's processes and raises ``KeyboardInterrupt``
  (no tracebacks from the workers, nothing left running);
* ``dask``: a ``dask.distributed`` cluster (``scheduler="tcp://HOST:PORT"``, or a ``Client`` / ``LocalCluster``
  given directly). Start its workers with ``OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1`` and ``--nthreads 1``
  (one run per core; the numbers do not depend on it, the speed does). ``on_dask_workers`` asks each worker
  something first (the study: what code it runs, ``d2slam.study.core.check_dask_workers``).

The function must be importable (a module-level function) and its arguments picklable. Results are placed by
index, so the output order never depends on which worker finished first. Progress
(:func:`d2slam.progress.progress`): a tqdm bar on a terminal, else a line on stderr every few seconds (CI, ``nohup``,
a pipe). With ``cost`` the items start in decreasing cost (``dispatch_order``: the longest first, ties in input order), one at a time as a worker frees up:
the last to start are the shortest, so both cores stay busy to the end instead of one finishing a long run alone.
"""

from __future__ import annotations

import os
import signal
from concurrent.futures import as_completed
from typing import Callable, Sequence

import numpy as np
from joblib.externals.loky import ProcessPoolExecutor

from d2slam.errors import D2SlamError
from d2slam.progress import progress as follow


def executor_name(jobs: int = 1, scheduler=None) -> str:
    if scheduler is not None:
        return "dask"
    return "serial" if int(jobs) <= 1 else "joblib"


def dispatch_order(costs: Sequence[float]) -> list[int]:
    """Indices of ``costs`` by decreasing cost; equal costs keep their input order."""
    return np.argsort(-np.asarray(costs, dtype=np.float64), kind="stable").tolist()


def map_ordered(fn: Callable, items: Sequence, args: tuple = (), jobs: int = 1, scheduler=None,
                desc: str = "study", progress: bool | None = None,
                on_result: Callable[[int, object], None] | None = None,
                cost: Callable[[object], float] | None = None, unit: str = "run", cpu: list | None = None) -> list:
    """``[fn(item, *args) for item in items]`` on the chosen executor (see module docstring). ``on_result(i, result)``
    is called in this process as each result arrives (completion order), e.g. to save it at once. ``cost(item)``:
    the items start longest first (``dispatch_order``); the results stay in the order of ``items``. ``progress``:
    False shows nothing; otherwise ``desc: k/N units`` on stderr (:func:`d2slam.progress.progress`). ``cpu``: a list
    that gets each call's CPU seconds, wherever it ran (:class:`CpuTimed`)."""

    items = list(items)
    if not items:
        return []
    costs = [float(cost(it)) for it in items] if cost is not None else [1.0] * len(items)
    order = dispatch_order(costs)
    run = {"serial": _serial, "joblib": _joblib, "dask": _dask}[executor_name(jobs, scheduler)]
    results = run(CpuTimed(fn), items, order, args, jobs if scheduler is None else scheduler)
    out = [None] * len(items)
    try:
        for i, (res, seconds) in follow(results, total=len(items), desc=desc, unit=unit,
                                        enabled=progress is not False, weight=lambda r: costs[r[0]],
                                        total_weight=sum(costs)):
            out[i] = res
            if cpu is not None:
                cpu.append(seconds)
            if on_result is not None:
                on_result(i, res)
    finally:
        results.close()  # an error here (or Ctrl-C) stops the executor's workers
    return out


class CpuTimed:
    """``fn`` returning ``(its result, the CPU seconds of the call)``: user and system time of the process it runs in
    and of the child processes it waited for (the real ORB-SLAM3's worker). Picklable, for any executor; on a Dask
    worker of more than one thread the process's time holds its other threads' too."""

    def __init__(self, fn: Callable):
        self.fn = fn

    def __call__(self, *args):
        t0 = process_cpu_s()
        res = self.fn(*args)
        return res, process_cpu_s() - t0


def process_cpu_s(children: bool = True) -> float:
    """User + system seconds of this process and (``children``) of the child processes it waited for."""
    t = os.times()
    return t.user + t.system + ((t.children_user + t.children_system) if children else 0.0)


def _serial(fn, items, order, args, _jobs):
    for i in order:
        yield i, fn(items[i], *args)


# The workers' BLAS and OpenMP thread counts (one job per core; the numbers do not depend on them).
WORKER_ENV = {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}


def _joblib(fn, items, order, args, jobs):
    """(index, result) in completion order from ``jobs`` loky processes; the pool is shut down when the generator
    ends or is closed (its workers killed unless every result came)."""
    pool = ProcessPoolExecutor(max_workers=int(jobs), env=WORKER_ENV, initializer=_ignore_sigint)
    try:
        with _sigint_deferred():  # the workers start now (first submit) and inherit the block
            # submitted in ``order``: the pool starts them so, one per worker as it frees up
            futures = {pool.submit(fn, items[i], *args): i for i in order}
        for fut in as_completed(futures):
            yield futures[fut], fut.result()
    except BaseException:
        pool.shutdown(wait=True, kill_workers=True)
        raise
    pool.shutdown(wait=True)


def _ignore_sigint() -> None:
    """Worker initializer: Ctrl-C is the parent's to handle (a replaced worker does not inherit it at start)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)


class _sigint_deferred:
    """SIGINT blocked in this thread for the duration: processes started meanwhile inherit the block, so a Ctrl-C
    cannot reach a worker before its initializer ignores it, and a Ctrl-C that comes meanwhile stays pending here
    and is delivered (``KeyboardInterrupt``) when the block ends, instead of being lost."""

    def __enter__(self):
        self._prev = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
        return self

    def __exit__(self, *exc):
        signal.pthread_sigmask(signal.SIG_SETMASK, self._prev)
        return False


def _indexed(i, fn, item, args):
    return i, fn(item, *args)


def dask_client(scheduler):
    """``(client, own)``: a ``distributed.Client`` of ``scheduler`` (an address ``tcp://HOST:PORT``, a ``Client``, or a
    cluster object such as a ``LocalCluster``), and whether it was made here (then the caller closes it)."""
    try:
        from distributed import Client
    except ImportError as exc:  # pragma: no cover - dask/distributed are in environment.txt
        raise D2SlamError(f"--scheduler needs dask.distributed: {exc}") from None
    if isinstance(scheduler, Client):
        return scheduler, False
    if hasattr(scheduler, "scheduler_address"):  # a LocalCluster / any cluster object
        return Client(scheduler), True
    address = str(scheduler)
    if "://" not in address:
        raise D2SlamError(f"--scheduler must be an address like tcp://HOST:PORT, got {address!r}")
    try:
        return Client(address, timeout="10s"), True
    except (OSError, TimeoutError) as exc:
        raise D2SlamError(f"cannot reach the Dask scheduler at {address}: {exc}") from None


def on_dask_workers(scheduler, fn: Callable) -> dict:
    """``fn()`` on every worker connected to the Dask scheduler now: worker (its name, else its address) -> what
    it returned, or the exception it raised there (one that cannot import ``fn``'s module too)."""
    client, own = dask_client(scheduler)
    try:
        names = {a: w.get("name", a) for a, w in client.scheduler_info(n_workers=-1)["workers"].items()}
        got = client.run(fn, on_error="return") if names else {}
        return {str(names.get(a, a)): r for a, r in got.items()}
    finally:
        if own:
            client.close()


def _dask(fn, items, order, args, scheduler):
    """(index, result) in completion order from a Dask cluster (the client closed at the end if made here)."""
    from distributed import as_completed

    client, own = dask_client(scheduler)
    try:
        # Dask runs the highest priority first
        futures = [client.submit(_indexed, i, fn, items[i], args, pure=False, priority=len(order) - rank)
                   for rank, i in enumerate(order)]
        for fut in as_completed(futures):
            yield fut.result()
    finally:
        if own:
            client.close()
