"""Rerun's web viewer, served so that it talks to this lab only.

The page rerun-sdk serves loads fonts from the internet and sends usage data (tel.rerun.io) from the
browser, and it has no option to stop that. So twinmesh serves the viewer's files itself, taken from
rerun-sdk's own web server on an internal port (the files come with the package: no internet) and
kept in memory, with a Content-Security-Policy that lets the page connect to nothing but its own
origin and the recording's gRPC port: the browser refuses every other request before it leaves.
The page's links to web fonts (which the policy would refuse anyway) are taken out of it.

The address a browser opens is a page of ours (`FRAME_PAGE`) that holds the viewer's own page in a
frame. A browser without a GPU draws WebGL in software, and then the number of pixels sets how many
frames a second the viewer draws, and so how soon a change shows (docs: the benchmarks page). In such
a browser the frame lays the viewer out smaller and shows it enlarged, so that it draws no more than
`SOFTWARE_PIXELS` (a 1280x800 window: half its size, enlarged twice). `scale=N` in the address
chooses (1 = every pixel, up to 4); `auto`, the default, does this where WebGL reports a software
renderer and draws every pixel elsewhere. The browser maps clicks and keys through the enlargement
into the frame, so the viewer works as it does alone.
"""
from __future__ import annotations

import json
import re
import socket
import string
import threading
import urllib.request
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from urllib.parse import quote, urlsplit

POLICY = ("default-src 'self'; script-src 'self' 'unsafe-inline' 'wasm-unsafe-eval'; "
          "style-src 'self' 'unsafe-inline'; img-src 'self' data: blob:; font-src 'self' data:; "
          "worker-src 'self' blob:; connect-src 'self' http://*:{grpc} https://*:{grpc}")
_KEPT_HEADERS = ("Content-Type", "Content-Encoding")
_REMOTE_LINK = re.compile(rb"<link\b[^>]*?https?://[^>]*>", re.S)


VIEWER_PAGE = "/viewer.html"  # Rerun's own page (rerun-sdk's `/`), in the frame of ours
# A software renderer's frames a second follow the pixels it draws: 640x400 kept up with a busy lab where
# 1280x800 fell minutes behind (docs: the benchmarks page). `auto` scales the viewer so that it draws no more.
SOFTWARE_PIXELS = 640 * 400
SOFTWARE_RENDERERS = ("swiftshader", "llvmpipe", "softpipe", "software", "basic render")
_FRAME_TEMPLATE = string.Template("""<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>twinmesh 3D view</title>
<style>html,body{margin:0;width:100%;height:100%;overflow:hidden;background:#0d1011}
iframe{position:absolute;left:0;top:0;border:0;transform-origin:0 0}</style></head>
<body><iframe id="viewer" title="Rerun viewer" allow="fullscreen; clipboard-read; clipboard-write"></iframe>
<script>
(function () {
  var asked = new URLSearchParams(location.search);
  var scale = asked.get("scale") || "auto";
  asked.delete("scale");
  function software() {
    try {
      var gl = document.createElement("canvas").getContext("webgl2") ||
               document.createElement("canvas").getContext("webgl");
      if (!gl) return false;
      var info = gl.getExtension("WEBGL_debug_renderer_info");
      var name = String(gl.getParameter(info ? info.UNMASKED_RENDERER_WEBGL : gl.RENDERER)).toLowerCase();
      return $software.some(function (s) { return name.indexOf(s) >= 0; });
    } catch (e) { return false; }
  }
  var soft = scale === "auto" && software();
  var k = 1;
  var frame = document.getElementById("viewer");
  function fit() {
    // auto: a software renderer draws at most $pixels pixels (a 1280x800 window: half its size)
    k = scale !== "auto" ? Math.min(4, Math.max(1, Number(scale) || 1))
      : soft ? Math.min(4, Math.max(1, Math.sqrt(innerWidth * innerHeight / $pixels))) : 1;
    frame.style.width = (innerWidth / k) + "px";
    frame.style.height = (innerHeight / k) + "px";
    frame.style.transform = k === 1 ? "" : "scale(" + k + ")";
    document.documentElement.dataset.scale = String(Math.round(k * 100) / 100);
  }
  addEventListener("resize", fit);
  fit();
  frame.src = "$viewer" + (asked.toString() ? "?" + asked.toString() : "");
  frame.addEventListener("load", function () { frame.focus(); });
})();
</script></body></html>
""")
FRAME_PAGE = _FRAME_TEMPLATE.substitute(  # what a browser opens at `/`
    software=json.dumps(SOFTWARE_RENDERERS), pixels=SOFTWARE_PIXELS, viewer=VIEWER_PAGE.lstrip("/"))


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
                try:
                    self.send_response(status)
                    for name, value in headers:
                        self.send_header(name, value)
                    self.send_header("Content-Security-Policy", policy)
                    self.send_header("Content-Length", str(len(body)))
                    self.end_headers()
                    self.wfile.write(body)
                except (BrokenPipeError, ConnectionResetError):
                    pass  # the browser left (a tab closed while the viewer loaded): nothing to answer

            def log_message(self, *args) -> None:
                pass

        self.httpd = ThreadingHTTPServer(address, Handler)
        self.httpd.daemon_threads = True
        self._thread = threading.Thread(target=self.httpd.serve_forever, name="web-viewer", daemon=True)
        self._thread.start()

    def file(self, path: str) -> tuple[int, list[tuple[str, str]], bytes]:
        """Our page at `/`; a file of the viewer (fetched once from rerun-sdk's server, then from memory),
        its own page at `VIEWER_PAGE`."""
        if path in ("/", "/index.html"):
            return 200, [("Content-Type", "text/html; charset=utf-8")], FRAME_PAGE.encode()
        if path == VIEWER_PAGE:
            path = "/"
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
