"""``d2slam assets fetch|list``: the segmentation models and real TUM data a checkout needs (not in git)."""

from __future__ import annotations

from d2slam import assets as A
from d2slam.errors import D2SlamError


def register(sub) -> None:
    parser = sub.add_parser(
        "assets", help="fetch (or list) the segmentation models and the real TUM frames",
        description="The YOLOv8n-seg models, five TUM fr3 frames and the first 120 frames of TUM fr1/rpy (real/"
        "rgbd_dataset_freiburg1_rpy_head120) are read from the shared folder ($D2SLAM_SHARED, default ../shared) "
        "when it holds them, else from the cache ($D2SLAM_CACHE/assets). `fetch` downloads what neither holds from "
        "pinned GitHub commits (or $" + A.MIRROR_ENV + "), checks sha256 (for fr1/rpy: the whole sequence's lists, "
        "the lists cut to the first 120 frames and every image) and derives the float models from the int8 one; it "
        "does nothing when everything is found. An interrupted fetch of fr1/rpy resumes where it stopped.")
    parser.add_argument("action", choices=["fetch", "list"], help="fetch the missing assets, or list where each is")
    parser.add_argument("--full-real", action="store_true",
                        help="fetch also the whole TUM fr1/rpy sequence (723 RGB + 722 depth images, about 440 MB; "
                        "for development) from the same pinned copy into $D2SLAM_CACHE/real/rgbd_dataset_freiburg1_rpy: "
                        "its lists are sha256-checked; no per-image checksum is known, so every listed image must "
                        "arrive and decode")
    parser.add_argument("--timeout", type=float, default=None, metavar="S",
                        help="connection / read timeout in seconds (default DataConfig.download_timeout)")
    parser.set_defaults(func=run)


def run(args) -> int:
    if args.action == "list":
        if args.full_real:
            raise D2SlamError("--full-real goes with `fetch`")
        for rel in A.ALL_ASSETS:
            path = A.find(rel)
            print(f"{rel:44s} {path if path else 'missing'}")
        head, full = A.find_real_head(), A.real_full()
        print(f"{A.real_head_rel() + '/':44s} {head if head else 'missing'}")
        print(f"{A.REAL_DIR + '/' + A.real_pins()['sequence'] + '/':44s} "
              f"{full if full else 'missing (only with `d2slam assets fetch --full-real`)'}")
        return 0
    if args.timeout is not None and not args.timeout > 0:
        raise D2SlamError("--timeout must be positive")
    written = A.fetch_assets(timeout=args.timeout, echo=print)
    full = A.fetch_real_full(timeout=args.timeout, echo=print) if args.full_real else None
    print(f"assets: {len(written)} fetched or derived into {A.assets_cache()}" if written
          else "assets: all found, nothing to fetch")
    if args.full_real:
        print(f"assets: the whole TUM fr1/rpy sequence fetched into {full}" if full is not None
              else f"assets: the whole TUM fr1/rpy sequence is in {A.real_full()}, nothing to fetch")
    return 0
