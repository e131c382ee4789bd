"""A local HTTP server on 127.0.0.1 for the download tests, and a mirror of the pinned asset URLs.

``Server`` serves ``files`` (url path -> bytes) with Range support; it stops by itself after ``seconds``.
``python tests/local_http.py --mirror [--seconds S]`` serves the assets found by this checkout (shared folder or
cache) at their upstream paths, prints ``D2SLAM_ASSETS_MIRROR=URL`` and stops after ``S`` seconds (default 1800).
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


def asset_mirror(seconds: float = 600.0) -> Server:
    """A server holding every downloaded asset at its upstream path (read from the shared folder or the cache)."""
    from d2slam import assets

    srv = Server(seconds)
    for a in assets.DOWNLOADS:
        srv.files["/" + a.url_path] = assets.asset_path(a.path).read_bytes()
    return srv


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--mirror", action="store_true", required=True, help="serve the asset mirror")
    parser.add_argument("--seconds", type=float, default=1800.0, help="stop after this many seconds")
    args = parser.parse_args()
    server = asset_mirror(args.seconds)
    print(f"D2SLAM_ASSETS_MIRROR={server.url}", flush=True)
    server.thread.join()
