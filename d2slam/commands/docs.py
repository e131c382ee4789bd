"""``d2slam docs``: ``docs/results.md`` and the README's headline table, generated from a finished study."""

from __future__ import annotations

from d2slam.errors import D2SlamError
from d2slam.outputs import check_output_file
from d2slam.paths import checkout_root
from d2slam.study.docs import write_docs


def register(sub) -> None:
    p = sub.add_parser("docs", help="generate docs/results.md and the README's headline table from results/",
                       description="Render the study in RESULTS (runs.csv, manifest.json, plots/) as docs/results.md "
                       "and replace the README's headline table (between its two marker lines). Run it after "
                       "every new study; nothing else copies numbers.")
    p.add_argument("--results", default=None, metavar="DIR",
                   help="study folder (default: results/ of the d2slam checkout: the current folder, or the one the "
                   "package is installed from)")
    p.add_argument("--docs", default=None, metavar="DIR", help="docs folder (default: docs/ of the checkout)")
    p.add_argument("--readme", default=None, metavar="FILE", help="README to update (default: the checkout's "
                   "README.md)")
    p.add_argument("--no-readme", action="store_true", help="leave the README alone")
    p.set_defaults(func=run)


def run(args) -> int:
    if None in (args.results, args.docs, args.readme if not args.no_readme else ""):
        root = checkout_root()
        if root is None:
            raise D2SlamError("`d2slam docs` runs inside a d2slam checkout (results/ and docs/ beside pyproject.toml): "
                              "none in the current folder nor where the package is installed from; cd into one, or "
                              "give --results, --docs and --readme")
        args.results = args.results or str(root / "results")
        args.docs = args.docs or str(root / "docs")
        args.readme = args.readme or str(root / "README.md")
    check_output_file(f"{args.docs}/results.md", "--docs")
    readme = None if args.no_readme else check_output_file(args.readme, "--readme")
    for path in write_docs(args.results, args.docs, readme):
        print(f"wrote {path}")
    return 0
