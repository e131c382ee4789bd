"""Run a d2slam command with a fault at a chosen point: ``python tests/fault_hook.py TARGET N ACTION [MATCH] -- ARGS``.

``TARGET`` is ``module:attribute`` (``d2slam.synth.generate:write_image``, ``d2slam.slam.engine:Engine.process``,
``os:replace``); at its ``N``-th call whose arguments' text contains ``MATCH`` (any call without it) the process
sends itself ``ACTION`` (``SIGKILL``: dies on the spot, as ``kill -9``; ``SIGINT``: Ctrl-C, handled as in a terminal)
or, for ``sleep:S``, sleeps S seconds first (holding whatever it holds) and goes on. ``ARGS`` is the ``d2slam``
command line, or ``--python CODE`` to run Python code. The hook prints ``fault-hook: reached`` on stderr just before
it acts, so that a test can tell the point was reached (a run that ended before it would not print it).
"""

from __future__ import annotations

import importlib
import inspect
import os
import signal
import sys
import time


def install(target: str, n: int, action: str, match: str | None) -> None:
    module, qual = target.split(":")
    owner = importlib.import_module(module)
    *path, name = qual.split(".")
    for part in path:
        owner = getattr(owner, part)
    real = inspect.getattr_static(owner, name)
    kind = type(real) if isinstance(real, (staticmethod, classmethod)) else None
    func = real.__func__ if kind else real
    calls = 0

    def hooked(*args, **kwargs):
        nonlocal calls
        if match is None or match in repr(args) + repr(kwargs):
            calls += 1
            if calls == n:
                print("fault-hook: reached", file=sys.stderr, flush=True)
                sys.stdout.flush()
                if action.startswith("sleep:"):
                    time.sleep(float(action.split(":")[1]))
                else:
                    os.kill(os.getpid(), getattr(signal, action))
                    time.sleep(5)  # SIGINT: the handler raises KeyboardInterrupt here
        return func(*args, **kwargs)

    setattr(owner, name, kind(hooked) if kind else hooked)


def main() -> int:
    sep = sys.argv.index("--")
    spec, args = sys.argv[1:sep], sys.argv[sep + 1:]
    signal.signal(signal.SIGINT, signal.default_int_handler)  # as in a terminal, whatever the parent ignores
    install(spec[0], int(spec[1]), spec[2], spec[3] if len(spec) > 3 else None)
    if args[:1] == ["--python"]:
        try:
            exec(compile(args[1], "<fault-hook>", "exec"), {"__name__": "__main__"})
        except KeyboardInterrupt:
            print("d2slam: interrupted", file=sys.stderr)
            return 130
        return 0
    from d2slam.cli import main as cli

    return cli(args)


if __name__ == "__main__":
    sys.exit(main())
