"""``d2slam download SEQUENCE --to DIR``: fetch, verify and extract an official TUM RGB-D sequence."""

from __future__ import annotations

from d2slam.data import download as dl
from d2slam.errors import D2SlamError


def register(sub) -> None:
    parser = sub.add_parser(
        "download", help="download, verify and extract a TUM RGB-D sequence",
        description="Download an official TUM RGB-D archive (resumable), verify it (HTTP length, gzip/tar "
        "integrity, expected files, sha256 against the record of the first download on this machine) and "
        "extract it into DIR. The server is the official one with its older mirror as fallback, or "
        f"${dl.MIRROR_ENV}, or --base-url. Without network it fails fast and says how to download manually.")
    parser.add_argument("sequence", nargs="?", metavar="SEQUENCE",
                        help="e.g. fr3_walking_xyz (also freiburg3_walking_xyz, rgbd_dataset_freiburg3_walking_xyz)")
    parser.add_argument("--to", metavar="DIR", help="destination folder (created)")
    parser.add_argument("--base-url", metavar="URL",
                        help=f"server holding <URL>/freiburgN/<archive>.tgz (default: ${dl.MIRROR_ENV} or the "
                        "official server)")
    parser.add_argument("--archive", metavar="FILE", help="verify and extract an archive downloaded by hand "
                        "instead of downloading")
    parser.add_argument("--keep-archive", action="store_true", help="keep the .tgz after extraction")
    parser.add_argument("--force", action="store_true", help="download again even if DIR holds the sequence")
    parser.add_argument("--timeout", type=float, default=dl.CONNECT_TIMEOUT, metavar="S",
                        help="connection / read timeout in seconds (default %(default)s)")
    parser.add_argument("--list", action="store_true", help="list the known sequences and exit")
    parser.set_defaults(func=run)


def run(args) -> int:
    if args.list:
        print(dl.format_list())
        return 0
    if not args.sequence or not args.to:
        raise D2SlamError("give a SEQUENCE and --to DIR (or --list to see the known sequences)")
    if not args.timeout > 0:
        raise D2SlamError("--timeout must be positive")
    dl.download_sequence(args.sequence, args.to, base_url=args.base_url, archive=args.archive,
                         keep_archive=args.keep_archive, force=args.force, timeout=args.timeout,
                         log=print)
    return 0
