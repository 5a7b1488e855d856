"""A static HTTP server with range requests, for the tests of inputs by URL (stdlib only).

``python range_server.py ROOT LOG`` serves the files under ROOT on 127.0.0.1 (a free port,
printed on the first line of stdout): GET and HEAD, ``Range: bytes=a-b`` answered 206 with those
bytes (``?noranges`` in the URL: the Range header ignored, as by a server without ranges). Each
request is appended to LOG as a JSON line ``[method, path, range or null, body bytes]``.

It runs in a process of its own, not a thread of the test: GDAL makes some requests (a sidecar
read lazily by rasterio) with Python's GIL held, which a server thread could never answer.
"""

from __future__ import annotations

import http.server
import json
import pathlib
import re
import sys

_RANGE = re.compile(r"bytes=(\d+)-(\d*)$")


class RangeHandler(http.server.BaseHTTPRequestHandler):
    def do_HEAD(self):
        self._answer(body=False)

    def do_GET(self):
        self._answer(body=True)

    def _answer(self, body: bool):
        path = self.server.root / self.path.split("?")[0].lstrip("/")
        ranges = "noranges" not in self.path
        if not path.is_file():
            self._log(None, 0)
            self.send_error(404)
            return
        data = path.read_bytes()
        ranged = self.headers.get("Range") if ranges else None
        status, start, stop = 200, 0, len(data)
        if ranged:
            m = _RANGE.match(ranged.strip())
            if m is None or int(m.group(1)) >= len(data):
                self._log(ranged, 0)
                self.send_error(416)
                return
            start = int(m.group(1))
            stop = min(int(m.group(2)) + 1 if m.group(2) else len(data), len(data))
            status = 206
        chunk = data[start:stop]
        self.send_response(status)
        self.send_header("Content-Length", str(len(chunk)))
        self.send_header("Accept-Ranges", "bytes")
        if status == 206:
            self.send_header("Content-Range", f"bytes {start}-{stop - 1}/{len(data)}")
        self.end_headers()
        if body:
            self.wfile.write(chunk)
        self._log(ranged, len(chunk) if body else 0)

    def _log(self, ranged, n: int) -> None:
        with open(self.server.log_path, "a") as f:
            f.write(json.dumps([self.command, self.path, ranged, n]) + "\n")

    def log_message(self, *args):  # quiet
        pass


def main(root: str, log: str) -> None:
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), RangeHandler)
    server.root, server.log_path = pathlib.Path(root), log
    print(server.server_address[1], flush=True)
    server.serve_forever()


if __name__ == "__main__":
    main(*sys.argv[1:3])
