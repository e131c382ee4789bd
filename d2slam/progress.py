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

from tqdm import tqdm

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


class Progress:
    """Progress pushed by its caller (``update(n)``, then ``close()``): a tqdm bar when ``stream`` (stderr) is a
    terminal; otherwise ``d2slam: DESC: k/N UNITs, 12 s, about 30 s left`` every ``interval`` seconds
    (``CliConfig.progress_log_s``) and a last line at ``close()``; nothing when not ``enabled``. ``total_weight``:
    the work in all when ``update`` is given each step's weight (the time left then follows the work done)."""

    def __init__(self, desc: str, total: int | None, unit: str = "frame", enabled: bool = True, stream=None,
                 interval: float | None = None, clock=time.monotonic, total_weight: float | None = None):
        self.desc, self.total, self.unit, self.enabled = desc, total, unit, enabled
        self.stream = stream or sys.stderr
        self.every = CLI.progress_log_s if interval is None else float(interval)
        self.clock = clock
        self.of_w = total if total_weight is None else total_weight  # the work in all: items, or their weights
        self.done, self.done_w = 0, 0.0
        self.start = self.last = clock()
        self.bar = None
        if enabled and _is_tty(self.stream):
            self.bar = tqdm(total=total, desc=desc, unit=unit, file=self.stream)

    def update(self, n: int = 1, weight: float | None = None) -> None:
        self.done += n
        self.done_w += float(n) if weight is None else weight
        if self.bar is not None:
            self.bar.update(n)
            return
        now = self.clock()
        if self.enabled and now - self.last >= self.every and (not self.total or self.done < self.total):
            self.last = now
            share = self.done_w / self.of_w if self.of_w else 0.0
            left = f", about {duration((now - self.start) * (1.0 - share) / share)} left" if share > 0 else ""
            print(f"d2slam: {self.desc}: {self.done}{self._of()} {self.unit}s, {duration(now - self.start)}{left}",
                  file=self.stream, flush=True)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()
        elif self.enabled:
            print(f"d2slam: {self.desc}: {self.done}{self._of()} {self.unit}s in "
                  f"{duration(self.clock() - self.start)}", file=self.stream, flush=True)

    def _of(self) -> str:
        return f"/{self.total}" if self.total else ""


def progress(iterable: Iterable[T], total: int | None = None, desc: str = "", unit: str = "frame",
             enabled: bool = True, stream=None, interval: float | None = None, clock=time.monotonic,
             weight: Callable[[T], float] | None = None, total_weight: float | None = None) -> Iterator[T]:
    """Iterate over ``iterable`` showing progress on stderr (or ``stream``), as :class:`Progress` says. Items of
    unequal cost (a 1200-frame sequence beside 300-frame ones): ``weight(item)`` and ``total_weight`` make the time
    left follow the work done, not the count."""
    if total is None and hasattr(iterable, "__len__"):
        total = len(iterable)  # type: ignore[arg-type]
    if not enabled:
        yield from iterable
        return
    stream = stream or sys.stderr
    if _is_tty(stream):
        yield from tqdm(iterable, total=total, desc=desc, unit=unit, file=stream)
        return
    bar = Progress(desc, total, unit, True, stream, interval, clock, total_weight if weight is not None else None)
    for item in iterable:
        yield item
        bar.update(1, None if weight is None else weight(item))
    bar.close()
