"""``d2slam demo``: for now, generate a short synthetic walking_xyz sequence into the cache and describe it."""

from __future__ import annotations


def register(sub) -> None:
    p = sub.add_parser("demo", help="generate a short synthetic walking_xyz sequence and print what it made",
                       description="Generate a short synthetic walking_xyz sequence (and its static twin) into the "
                       "cache (d2slam.paths.cache_dir('demo')) and print the files, people and coverage.")
    p.add_argument("--frames", type=int, default=60, help="frames to generate (default 60)")
    p.add_argument("--seed", type=int, default=0)
    p.set_defaults(func=run)


def run(args) -> int:
    from d2slam.commands.synth import summarise
    from d2slam.paths import cache_dir
    from d2slam.synth.generate import generate

    root = cache_dir("demo")
    for twin in (False, True):
        out = root / ("walking_xyz" + ("_static_twin" if twin else ""))
        result = generate("walking_xyz", out, frames=args.frames, seed=args.seed, static_twin=twin)
        print(summarise(result))
        files = sorted(p.name for p in out.iterdir())
        print(f"  contents: {', '.join(files)}")
    print(f"Read it with d2slam.data (TUM layout) or look at the images under {root}.")
    return 0
