"""One-off costs said before they start, and followed while they run.

``announce(what, seconds)`` prints one line to stderr with an estimate ("d2slam: generating ... (about 50 s)") before
a long step that happens once (generating a synthetic sequence, segmenting a sequence into the mask cache).
``progress(iterable, total, desc)`` then shows how far it got: a tqdm bar when stderr is a terminal, else a line
every ``CliConfig.progress_log_s`` seconds with the count, the time spent and the time left, so that logs of
non-interactive runs (CI, ``nohup``, a pipe) show it too.
"""

from __future__ import annotations

import sys
import time
from typing import Callable, Iterable, Iterator, TypeVar

from d2slam.config import CLI

T = TypeVar("T")


def duration(seconds: float) -> str:
    """A rounded, readable duration: "8 s", "45 s", "3 min", "1.5 h"."""
    s = max(0.0, float(seconds))
    if s < 60:
        return f"{max(1, round(s))} s"
    if s < 3600:
        return f"{round(s / 60)} min"
    return f"{s / 3600:.1f} h"


def announce(what: str, seconds: float | None = None, stream=None) -> None:
    """``d2slam: WHAT (about 2 min)`` on stderr (or ``stream``), before the step starts."""
    about = f" (about {duration(seconds)})" if seconds is not None else ""
    print(f"d2slam: {what}{about}", file=stream or sys.stderr, flush=True)


def _is_tty(stream) -> bool:
    isatty = getattr(stream, "isatty", None)
    try:
        return bool(isatty and isatty())
    except ValueError:  # a closed stream
        return False


def progress(iterable: Iterable[T], total: int | None = None, desc: str = "", unit: str = "frame",
             enabled: bool = True, stream=None, interval: float | None = None, clock=time.monotonic,
             weight: Callable[[T], float] | None = None, total_weight: float | None = None) -> Iterator[T]:
    """Iterate over ``iterable`` showing progress on stderr (or ``stream``): a tqdm bar on a terminal; otherwise
    ``d2slam: DESC: k/N UNITs, 12 s, about 30 s left`` every ``interval`` seconds (``CliConfig.progress_log_s``) and
    a last line when it ends. ``enabled=False``: nothing is shown. Items of unequal cost (a 1200-frame sequence
    beside 300-frame ones): ``weight(item)`` and ``total_weight`` make the time left follow the work done, not the
    count."""
    stream = stream or sys.stderr
    if total is None and hasattr(iterable, "__len__"):
        total = len(iterable)  # type: ignore[arg-type]
    if not enabled:
        yield from iterable
        return
    if _is_tty(stream):
        from tqdm import tqdm

        yield from tqdm(iterable, total=total, desc=desc, unit=unit, file=stream)
        return
    every = CLI.progress_log_s if interval is None else float(interval)
    start = last = clock()
    done, done_w = 0, 0.0
    of_w = total if weight is None else total_weight  # the work in all: items, or their summed weights
    of = f"/{total}" if total else ""
    for item in iterable:
        yield item
        done += 1
        done_w += 1.0 if weight is None else weight(item)
        now = clock()
        if now - last >= every and (not total or done < total):
            last = now
            share = done_w / of_w if of_w else 0.0
            left = f", about {duration((now - start) * (1.0 - share) / share)} left" if share > 0 else ""
            print(f"d2slam: {desc}: {done}{of} {unit}s, {duration(now - start)}{left}", file=stream, flush=True)
    print(f"d2slam: {desc}: {done}{of} {unit}s in {duration(clock() - start)}", file=stream, flush=True)
