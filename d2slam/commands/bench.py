"""``d2slam bench TOPIC``: benchmark commands that print figures."""

from __future__ import annotations

from d2slam import bench


def register(sub) -> None:
    parser = sub.add_parser("bench", help="run a benchmark that prints figures (speed, accuracy)",
                            description="Benchmarks: " + ", ".join(bench.topics()))
    topics = parser.add_subparsers(dest="topic", metavar="TOPIC", required=True)
    for name in bench.topics():
        module = bench.load(name)
        text = module.DESCRIPTION.replace("%", "%%")  # argparse %-formats help texts: "3 % of the image"
        p = topics.add_parser(name, help=text, description=text)
        module.add_arguments(p)
        p.set_defaults(func=module.run)
