"""``d2slam bench TOPIC``: benchmark commands that print figures."""

from __future__ import annotations

from d2slam import bench


def register(sub) -> None:
    parser = sub.add_parser("bench", help="run a benchmark that prints figures (speed, accuracy)",
                            description="Benchmarks: " + ", ".join(bench.topics()))
    topics = parser.add_subparsers(dest="topic", metavar="TOPIC", required=True)
    for name in bench.topics():
        module = bench.load(name)
        # argparse %-formats help texts ("3 % of the image"), not descriptions
        p = topics.add_parser(name, help=module.DESCRIPTION.replace("%", "%%"), description=module.DESCRIPTION)
        module.add_arguments(p)
        p.set_defaults(func=module.run)
