"""A local HTTP server on 127.0.0.1 for the download tests, and a mirror of the pinned asset URLs.

``Server`` serves ``files`` (url path -> bytes) with Range support; it stops by itself after ``seconds``.
``python tests/local_http.py --mirror [--seconds S]`` serves the assets found by this checkout (shared folder or
cache) at their upstream paths, prints ``D2SLAM_ASSETS_MIRROR=URL`` and stops after ``S`` seconds (default 1800).
It serves TUM fr1/rpy (the whole sequence's lists and images) when this checkout has the whole sequence
(``d2slam assets fetch --full-real``): a fetch of the head needs the whole lists.
"""

from __future__ import annotations

import argparse
import threading
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer


class Server:
    """Serves ``files`` (url path -> bytes). Options: ignore_range (answer 200 with the whole file), cut_first
    (the first response announces the full length but stops after that many bytes)."""

    def __init__(self, seconds: float = 600.0):
        self.files: dict[str, bytes] = {}
        self.requests: list[tuple[str, str | None]] = []
        self.ignore_range = False
        self.cut_first: int | None = None
        self.closed = False
        outer = self

        class Handler(BaseHTTPRequestHandler):
            def log_message(self, *args):
                pass

            def do_GET(self):
                rng = self.headers.get("Range")
                outer.requests.append((self.path, rng))
                data = outer.files.get(self.path)
                if data is None:
                    self.send_error(404, "Not Found")
                    return
                start = 0
                m = rng and not outer.ignore_range and rng.startswith("bytes=") and rng[6:].split("-")[0]
                if m:
                    start = int(m)
                    if start >= len(data):
                        self.send_response(416)
                        self.send_header("Content-Range", f"bytes */{len(data)}")
                        self.send_header("Content-Length", "0")
                        self.end_headers()
                        return
                    self.send_response(206)
                    self.send_header("Content-Range", f"bytes {start}-{len(data) - 1}/{len(data)}")
                else:
                    self.send_response(200)
                body = data[start:]
                self.send_header("Content-Length", str(len(body)))
                self.send_header("Accept-Ranges", "bytes")
                self.end_headers()
                if outer.cut_first is not None:
                    body, outer.cut_first = body[: outer.cut_first], None
                self.wfile.write(body)

        self.httpd = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.httpd.daemon_threads = True
        self.thread = threading.Thread(target=self.httpd.serve_forever, kwargs={"poll_interval": 0.02}, daemon=True)
        self.thread.start()
        self.url = f"http://127.0.0.1:{self.httpd.server_address[1]}"
        self.timer = threading.Timer(seconds, self.close)  # bounded: never outlives its use by long
        self.timer.daemon = True
        self.timer.start()

    def close(self):
        self.timer.cancel()
        if not self.closed:
            self.closed = True
            self.httpd.shutdown()
            self.httpd.server_close()


def real_url_path(rel: str) -> str:
    """The path of ``rel`` of TUM fr1/rpy (``rgb.txt``, ``rgb/<t>.png``) on a mirror of raw.githubusercontent.com."""
    from d2slam import assets

    pins = assets.real_pins()
    return f"/{pins['repository']}/{pins['commit']}/{pins['folder']}/{rel}"


def real_files(whole_lists: str, whole_images: bool = False) -> dict[str, bytes]:
    """TUM fr1/rpy at its mirror paths: the head's images (``d2slam.assets.real_head``) and, at the whole sequence's
    list paths, the whole sequence's lists (``whole_lists="real"``: ``d2slam.assets.real_full``; with
    ``whole_images`` every image they name too, 440 MB) or the head's cut lists (``"head"``: a whole sequence of 120
    frames, for tests that pin its lists with :func:`head_as_whole`)."""
    from d2slam import assets

    head = assets.real_head()
    files = {real_url_path(rel): (head / rel).read_bytes() for rel in assets.real_pins()["head"]["files"]}
    if whole_lists == "real":
        full = assets.real_full()
        files.update({real_url_path(name): (full / name).read_bytes() for name in assets.LISTS})
        if whole_images:
            files.update({real_url_path(rel): (full / rel).read_bytes() for rel in assets._listed(full)})
    else:
        files.update({real_url_path(name): (head / name).read_bytes() for name in assets.LISTS})
    return files


def head_as_whole(pins: dict) -> dict:
    """``pins`` (``d2slam.assets.real_pins()``) with the whole sequence's lists pinned to the head's: cutting the head
    from its own lists gives them back, so a mirror of the head (:func:`real_files` ``"head"``) serves both."""
    return {**pins, "lists": dict(pins["head"]["lists"])}


def asset_mirror(seconds: float = 600.0, whole_lists: str | None = None, whole_images: bool = False) -> Server:
    """A server holding every downloaded asset at its upstream path (read from the shared folder or the cache), and
    TUM fr1/rpy when ``whole_lists`` is given (:func:`real_files`)."""
    from d2slam import assets

    srv = Server(seconds)
    for a in assets.DOWNLOADS:
        srv.files["/" + a.url_path] = assets.asset_path(a.path).read_bytes()
    if whole_lists is not None:
        srv.files.update(real_files(whole_lists, whole_images))
    return srv


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--mirror", action="store_true", required=True, help="serve the asset mirror")
    parser.add_argument("--seconds", type=float, default=1800.0, help="stop after this many seconds")
    args = parser.parse_args()
    from d2slam.assets import find_real_head, real_full

    whole = bool(find_real_head() and real_full())
    server = asset_mirror(args.seconds, "real" if whole else None, whole_images=whole)
    print(f"D2SLAM_ASSETS_MIRROR={server.url}", flush=True)
    server.thread.join()
