"""``d2slam assets fetch|list``: the segmentation models and real TUM frames a checkout needs (not in git)."""

from __future__ import annotations


def register(sub) -> None:
    from d2slam import assets as A

    parser = sub.add_parser(
        "assets", help="fetch (or list) the segmentation models and the five real TUM frames",
        description="The YOLOv8n-seg models and five TUM fr3 frames are read from the shared folder "
        "($D2SLAM_SHARED, default ../shared) when it holds them, else from the cache ($D2SLAM_CACHE/assets). "
        "`fetch` downloads what neither holds from pinned GitHub commits (or $" + A.MIRROR_ENV + "), checks "
        "sha256 and derives the float models from the int8 one; it does nothing when everything is found.")
    parser.add_argument("action", choices=["fetch", "list"], help="fetch the missing assets, or list where each is")
    parser.add_argument("--timeout", type=float, default=None, metavar="S",
                        help="connection / read timeout in seconds (default DataConfig.download_timeout)")
    parser.set_defaults(func=run)


def run(args) -> int:
    from d2slam import assets as A
    from d2slam.errors import D2SlamError

    if args.action == "list":
        for rel in A.ALL_ASSETS:
            path = A.find(rel)
            print(f"{rel:44s} {path if path else 'missing'}")
        return 0
    if args.timeout is not None and not args.timeout > 0:
        raise D2SlamError("--timeout must be positive")
    written = A.fetch_assets(timeout=args.timeout, echo=print)
    print(f"assets: {len(written)} fetched or derived into {A.assets_cache()}" if written
          else "assets: all found, nothing to fetch")
    return 0
