"""The viewer's web server: a page on 127.0.0.1 that shows the live dashboard.

Routes: ``/`` the page; ``/frame.jpg?after=SEQ`` the newest dashboard newer than SEQ
(waits for it: the page asks for the next frame as soon as one has arrived, so frames
are pushed at the sensor's rate without polling); ``/stats.json`` rates, latency and
errors; ``POST /reset`` makes the next frames the no-contact reference. The server only
listens on the loopback interface.
"""

from __future__ import annotations

import json
import threading
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from urllib.parse import parse_qs, urlparse

from thintact_sdk.errors import ThinTactError
from thintact_sdk.viewer.live import LiveView
from thintact_sdk.viewer.page import page_html

LOOPBACK = "127.0.0.1"
FRAME_WAIT_S = 5.0
FIRST_FRAME_WAIT_S = 60.0
"""The first frame waits for the decoder and LUT to load (seconds on a busy machine)."""


class _Handler(BaseHTTPRequestHandler):
    server: _Server

    def log_message(self, format: str, *args: object) -> None:  # noqa: A002 - stdlib name
        """Quiet: no line per request."""

    def _send(self, status: int, body: bytes, content_type: str,
              headers: dict[str, str] | None = None) -> None:
        try:
            self.send_response(status)
            self.send_header("Content-Type", content_type)
            self.send_header("Content-Length", str(len(body)))
            self.send_header("Cache-Control", "no-store")
            for key, value in (headers or {}).items():
                self.send_header(key, value)
            self.end_headers()
            self.wfile.write(body)
        except (BrokenPipeError, ConnectionResetError):
            pass  # the browser went away

    def do_GET(self) -> None:  # noqa: N802 - http.server API
        live = self.server.live
        url = urlparse(self.path)
        if url.path in ("/", "/index.html"):
            self._send(HTTPStatus.OK, page_html(live.title).encode(), "text/html; charset=utf-8")
        elif url.path == "/frame.jpg":
            try:
                after = int(parse_qs(url.query).get("after", ["-1"])[0])
            except ValueError:
                after = -1
            wait = FRAME_WAIT_S if live.latest() is not None else FIRST_FRAME_WAIT_S
            published = live.wait_frame(after, wait)
            if published is None:
                self._send(HTTPStatus.SERVICE_UNAVAILABLE,
                           (live.error or "no frame yet").encode(), "text/plain; charset=utf-8")
                return
            self._send(HTTPStatus.OK, published.jpeg, "image/jpeg",
                       {"X-Frame-Seq": str(published.seq)})
            live.note_served(published)
        elif url.path == "/stats.json":
            self._send(HTTPStatus.OK, json.dumps(live.stats()).encode(), "application/json")
        else:
            self._send(HTTPStatus.NOT_FOUND, b"not found", "text/plain")

    def do_POST(self) -> None:  # noqa: N802 - http.server API
        if urlparse(self.path).path == "/reset":
            self.server.live.reset_reference()
            self._send(HTTPStatus.OK, b"reference reset", "text/plain")
        else:
            self._send(HTTPStatus.NOT_FOUND, b"not found", "text/plain")


class _Server(ThreadingHTTPServer):
    daemon_threads = True
    live: LiveView

    def __init__(self, port: int) -> None:
        super().__init__((LOOPBACK, port), _Handler)


class ViewerServer:
    """Serves a :class:`LiveView` on ``http://127.0.0.1:PORT/``.

    The port is bound when the server is made (so a busy port fails before the sensor is
    opened); :meth:`start` starts the frame loop and the serving thread.

    Parameters
    ----------
    port
        TCP port; 0 picks a free one (see :attr:`url`).

    Raises
    ------
    ThinTactError
        When the port is in use or cannot be opened.
    """

    def __init__(self, port: int = 0) -> None:
        try:
            self._httpd = _Server(port)
        except OSError as err:
            raise ThinTactError(
                f"cannot serve the viewer on {LOOPBACK}:{port}: {err.strerror or err}; "
                "pass --port N (0 picks a free port)"
            ) from None
        self._thread = threading.Thread(target=self._httpd.serve_forever, name="thintact-view-http",
                                        kwargs={"poll_interval": 0.1}, daemon=True)
        self.live: LiveView | None = None

    @property
    def url(self) -> str:
        """The page's address."""
        return f"http://{LOOPBACK}:{self._httpd.server_address[1]}/"

    def start(self, live: LiveView) -> ViewerServer:
        """Start ``live``'s frame loop and serve it."""
        self.live = self._httpd.live = live
        live.start()
        self._thread.start()
        return self

    def stop(self) -> None:
        """Stop serving and stop the frame loop. Safe to call twice."""
        if self._thread.is_alive():
            self._httpd.shutdown()
        self._httpd.server_close()
        if self.live is not None:
            self.live.stop()

    def __enter__(self) -> ViewerServer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()
