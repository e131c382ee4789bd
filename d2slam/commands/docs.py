"""``d2slam docs``: ``docs/results.md`` and the README's headline table, generated from a finished study."""

from __future__ import annotations


def register(sub) -> None:
    p = sub.add_parser("docs", help="generate docs/results.md and the README's headline table from results/",
                       description="Render the study in RESULTS (runs.csv, manifest.json, plots/) as docs/results.md "
                       "and replace the README's headline table (between its two marker lines). Run it after "
                       "every new study; nothing else copies numbers.")
    p.add_argument("--results", default="results", metavar="DIR", help="study folder (default: results)")
    p.add_argument("--docs", default="docs", metavar="DIR", help="docs folder (default: docs)")
    p.add_argument("--readme", default="README.md", metavar="FILE", help="README to update (default: README.md)")
    p.add_argument("--no-readme", action="store_true", help="leave the README alone")
    p.set_defaults(func=run)


def run(args) -> int:
    from d2slam.outputs import check_output_file
    from d2slam.study.docs import write_docs

    check_output_file(f"{args.docs}/results.md", "--docs")
    readme = None if args.no_readme else check_output_file(args.readme, "--readme")
    for path in write_docs(args.results, args.docs, readme):
        print(f"wrote {path}")
    return 0
