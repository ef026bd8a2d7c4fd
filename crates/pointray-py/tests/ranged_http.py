"""A local HTTP server for the tests of scene files at URLs: it serves a directory, answers
range requests (as object stores and web servers do), records the ranges it sent, and can
answer 503 for a while."""

import http.server
import os
import re
import threading
from functools import partial


class _Handler(http.server.SimpleHTTPRequestHandler):
    # Connections kept open between requests, as a web server's are.
    protocol_version = "HTTP/1.1"
    disable_nagle_algorithm = True

    def log_message(self, *args):
        pass

    def send_head(self):
        with self.server.lock:
            failing = self.server.down or (self.command == "GET" and self.server.failures > 0)
            if self.command == "GET" and self.server.failures > 0:
                self.server.failures -= 1
        if failing:
            self.send_error(503, "down")
            return None
        path = self.translate_path(self.path)
        if not os.path.isfile(path):
            self.send_error(404, "not found")
            return None
        size = os.path.getsize(path)
        asked = re.fullmatch(r"bytes=(\d+)-(\d*)", self.headers.get("Range", ""))
        start, end = (int(asked[1]), int(asked[2] or size - 1) + 1) if asked else (0, size)
        end = min(end, size)
        self.send_response(206 if asked else 200)
        self.send_header("Content-Length", str(end - start))
        self.send_header("Accept-Ranges", "bytes")
        if asked:
            self.send_header("Content-Range", f"bytes {start}-{end - 1}/{size}")
        self.end_headers()
        if self.command != "GET":
            return _Body(b"")
        with open(path, "rb") as f:
            f.seek(start)
            body = f.read(end - start)
        with self.server.lock:
            self.server.ranges.append((start, start + len(body)))
        return _Body(body)


class _Body:
    """What `copyfile` reads the response from."""

    def __init__(self, body):
        self.body = body

    def read(self, n=-1):
        body, self.body = self.body, b""
        return body

    def close(self):
        pass


class _Server(http.server.ThreadingHTTPServer):
    # Room for a client's many requests at once (socketserver's 5 drops connections, which
    # then wait a second for their retry).
    request_queue_size = 128
    daemon_threads = True


class RangedServer:
    """``with RangedServer(directory) as server``: ``server.url(name)``, ``server.sent``, ..."""

    def __init__(self, directory):
        self.httpd = _Server(("127.0.0.1", 0), partial(_Handler, directory=str(directory)))
        self.httpd.ranges, self.httpd.lock, self.httpd.down, self.httpd.failures = [], threading.Lock(), False, 0

    def url(self, name):
        return f"http://127.0.0.1:{self.httpd.server_address[1]}/{name}"

    @property
    def sent(self):
        """Bytes sent so far."""
        with self.httpd.lock:
            return sum(end - start for start, end in self.httpd.ranges)

    def sent_once(self):
        """Bytes sent so far, checking that no byte of the file was sent twice."""
        with self.httpd.lock:
            ranges = sorted(self.httpd.ranges)
        assert all(a[1] <= b[0] for a, b in zip(ranges, ranges[1:])), "a byte sent twice"
        return self.sent

    def set_down(self, down):
        """Every request answered 503 while down."""
        self.httpd.down = down

    def fail_next(self, requests):
        """The next `requests` GET requests answered 503."""
        with self.httpd.lock:
            self.httpd.failures = requests

    def forget(self):
        """Forgets the ranges sent so far."""
        with self.httpd.lock:
            self.httpd.ranges.clear()

    def __enter__(self):
        threading.Thread(target=self.httpd.serve_forever, daemon=True).start()
        return self

    def __exit__(self, *exc):
        self.httpd.shutdown()
        self.httpd.server_close()
