"""Rerun's web viewer, served so that it talks to this lab only.

The page rerun-sdk serves loads fonts from the internet and sends usage data (tel.rerun.io) from the
browser, and it has no option to stop that. So twinmesh serves the viewer's files itself, taken from
rerun-sdk's own web server on an internal port (the files come with the package: no internet) and
kept in memory, with a Content-Security-Policy that lets the page connect to nothing but its own
origin and the recording's gRPC port: the browser refuses every other request before it leaves.
The page's links to web fonts (which the policy would refuse anyway) are taken out of it.
"""
from __future__ import annotations

import re
import socket
import threading
import urllib.request
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from urllib.parse import quote, urlsplit

POLICY = ("default-src 'self'; script-src 'self' 'unsafe-inline' 'wasm-unsafe-eval'; "
          "style-src 'self' 'unsafe-inline'; img-src 'self' data: blob:; font-src 'self' data:; "
          "worker-src 'self' blob:; connect-src 'self' http://*:{grpc} https://*:{grpc}")
_KEPT_HEADERS = ("Content-Type", "Content-Encoding")
_REMOTE_LINK = re.compile(rb"<link\b[^>]*?https?://[^>]*>", re.S)


WILDCARDS = ("0.0.0.0", "::", "")  # every interface: a browser elsewhere reaches it by this machine's name


def viewer_url(host: str, port: int, grpc_port: int) -> str:
    """What a browser opens: the viewer at host:port, pointed at the gRPC stream on the same host."""
    if host in WILDCARDS:
        host = socket.gethostname()
    stream = f"rerun+http://{host}:{grpc_port}/proxy"
    return f"http://{host}:{port}/?url={quote(stream, safe='')}&hide_welcome_screen"


def free_port(host: str = "127.0.0.1") -> int:
    with socket.socket() as s:
        s.bind((host, 0))
        return s.getsockname()[1]


class ViewerServer:
    """The web viewer at `address` (host, port), allowed to reach the gRPC stream on `grpc_port` only."""

    def __init__(self, address: tuple[str, int], grpc_port: int):
        import rerun as rr

        self._origin_port = free_port()
        rr.serve_web_viewer(web_port=self._origin_port, open_browser=False)
        self._files: dict[str, tuple[int, list[tuple[str, str]], bytes]] = {}
        self._lock = threading.Lock()
        policy = POLICY.format(grpc=grpc_port)
        server = self

        class Handler(BaseHTTPRequestHandler):
            def do_GET(self) -> None:  # noqa: N802  (http.server's name)
                status, headers, body = server.file(urlsplit(self.path).path)
                self.send_response(status)
                for name, value in headers:
                    self.send_header(name, value)
                self.send_header("Content-Security-Policy", policy)
                self.send_header("Content-Length", str(len(body)))
                self.end_headers()
                self.wfile.write(body)

            def log_message(self, *args) -> None:
                pass

        self.httpd = ThreadingHTTPServer(address, Handler)
        self.httpd.daemon_threads = True
        self._thread = threading.Thread(target=self.httpd.serve_forever, name="web-viewer", daemon=True)
        self._thread.start()

    def file(self, path: str) -> tuple[int, list[tuple[str, str]], bytes]:
        """A file of the viewer (fetched once from rerun-sdk's server, then from memory)."""
        with self._lock:
            kept = self._files.get(path)
        if kept is not None:
            return kept
        try:
            with urllib.request.urlopen(f"http://127.0.0.1:{self._origin_port}{path}", timeout=30) as r:
                body = r.read()
                if path in ("/", "/index.html"):
                    body = _REMOTE_LINK.sub(b"", body)
                answer = (r.status, [(h, r.headers[h]) for h in _KEPT_HEADERS if r.headers[h]], body)
        except urllib.error.HTTPError as e:
            return e.code, [("Content-Type", "text/plain")], f"{e.code} {e.reason}".encode()
        except OSError as e:
            return 502, [("Content-Type", "text/plain")], f"the viewer's files are not available: {e}".encode()
        with self._lock:
            self._files[path] = answer
        return answer

    def close(self) -> None:
        self.httpd.shutdown()
        self.httpd.server_close()
