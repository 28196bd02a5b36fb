"""The viewer's web server: a page on 127.0.0.1 that shows the live dashboard.

One server shows one or several sensors (one panel group each); ``sensor=K`` (default 0)
picks one. Routes: ``/`` the page; ``/frame.jpg?sensor=K&after=SEQ`` the newest dashboard
newer than SEQ (waits for it: the page asks for the next frame as soon as one has arrived,
so frames are pushed at the sensor's rate without polling); ``/stats.json?sensor=K``
rates, latency, errors and the recording; ``POST /reset?sensor=K`` makes the next frames
the no-contact reference; ``POST /snapshot?sensor=K`` writes the newest frame's
reconstruction PNG and depth ``.npy``; ``POST /record/start?sensor=K`` and
``POST /record/stop?sensor=K`` record the live frames (:mod:`thintact_sdk.apps.viewer.snapshots`;
the paths written are in the JSON reply). The server only listens on the loopback
interface.

Security model (docs/viewer.md#security)
-----------------------------------------
Binding 127.0.0.1 keeps other machines out, but not other web sites open in a browser on
the same machine. So every request must name the server itself in its ``Host`` header
(``127.0.0.1:PORT``, ``localhost:PORT`` or ``[::1]:PORT``; anything else is 403, which
defeats DNS rebinding), and every state-changing request (``POST``, ``PUT``, ``DELETE``,
``PATCH``) must in addition

- carry no ``Origin`` or a same-origin one (``http://`` + one of those hosts),
- not be marked cross-site by the browser (``Sec-Fetch-Site``), and
- carry the server's random token in the :data:`TOKEN_HEADER` header. The token is made
  when the server is made, is embedded only in the page served to a same-origin request,
  and is sent back by the page's script; a custom header also forces a CORS preflight,
  which this server never grants.

Every refusal is 403 with a one-line reason and changes nothing. Responses forbid framing
(``X-Frame-Options: DENY``, CSP ``frame-ancestors 'none'``) so the buttons cannot be
clicked through another site's frame.
"""

from __future__ import annotations

import hmac
import json
import secrets
import threading
from collections.abc import Sequence
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from urllib.parse import parse_qs

from thintact_sdk.apps.viewer.frame_loop import LiveView
from thintact_sdk.apps.viewer.page import page_html
from thintact_sdk.errors import ThinTactError

LOOPBACK = "127.0.0.1"
FRAME_WAIT_S = 5.0
FIRST_FRAME_WAIT_S = 60.0
"""The first frame waits for the decoder and LUT to load (seconds on a busy machine)."""
TOKEN_HEADER = "X-ThinTact-Token"
"""Request header that carries the server's token on state-changing requests."""
STATE_CHANGING = frozenset({"POST", "PUT", "DELETE", "PATCH"})
MAX_BODY_BYTES = 64 * 1024
"""Largest request body read (and ignored); a longer one is refused with 413."""
SOCKET_TIMEOUT_S = 30.0
"""A client that stops sending mid-request is dropped after this long."""


def allowed_hosts(port: int) -> frozenset[str]:
    """The ``Host`` header values (lower case) a server on loopback ``port`` answers."""
    hosts = {f"127.0.0.1:{port}", f"localhost:{port}", f"[::1]:{port}"}
    if port == 80:  # a browser leaves the default port out of Host
        hosts |= {"127.0.0.1", "localhost", "[::1]"}
    return frozenset(hosts)


class _Handler(BaseHTTPRequestHandler):
    server: _Server
    timeout = SOCKET_TIMEOUT_S

    def log_message(self, format: str, *args: object) -> None:  # noqa: A002 - stdlib name
        """Quiet: no line per request."""

    def _send(self, status: int, body: bytes, content_type: str,
              headers: dict[str, str] | None = None) -> None:
        try:
            self.send_response(status)
            self.send_header("Content-Type", content_type)
            self.send_header("Content-Length", str(len(body)))
            self.send_header("Cache-Control", "no-store")
            self.send_header("X-Content-Type-Options", "nosniff")
            self.send_header("X-Frame-Options", "DENY")
            self.send_header("Referrer-Policy", "no-referrer")
            for key, value in (headers or {}).items():
                self.send_header(key, value)
            self.end_headers()
            self.wfile.write(body)
        except (BrokenPipeError, ConnectionResetError, TimeoutError):
            self.close_connection = True  # the browser went away

    def _text(self, status: int, message: str) -> None:
        self._send(status, (message + "\n").encode(), "text/plain; charset=utf-8")

    # -- the checks of the security model ----------------------------------------------
    def _host_refusal(self) -> str | None:
        hosts = self.headers.get_all("Host") or []
        if len(hosts) != 1:
            return "the request must carry exactly one Host header"
        if hosts[0].strip().lower() not in self.server.hosts:
            return "this viewer only answers requests addressed to its own loopback address"
        return None

    def _state_change_refusal(self) -> str | None:
        origins = self.headers.get_all("Origin") or []
        if len(origins) > 1 or (origins and origins[0].strip().lower() not in self.server.origins):
            return "cross-origin request refused"
        site = (self.headers.get("Sec-Fetch-Site") or "").strip().lower()
        if site not in ("", "same-origin", "none"):
            return "cross-site request refused"
        tokens = self.headers.get_all(TOKEN_HEADER) or []
        if len(tokens) != 1 or not hmac.compare_digest(
                tokens[0].strip().encode("utf-8", "replace"), self.server.token.encode()):
            return f"missing or wrong {TOKEN_HEADER} header (use the viewer's page)"
        return None

    def _drain_body(self) -> bool:
        """Read and drop the request body; False (after answering) when it is refused."""
        lengths = self.headers.get_all("Content-Length") or []
        if self.headers.get("Transfer-Encoding"):
            self.close_connection = True
            self._text(HTTPStatus.NOT_IMPLEMENTED, "chunked request bodies are not accepted")
            return False
        if not lengths:
            return True
        text = lengths[0].strip()
        if len(set(lengths)) > 1 or not text.isascii() or not text.isdigit():
            self.close_connection = True
            self._text(HTTPStatus.BAD_REQUEST, "bad Content-Length")
            return False
        length = int(text)
        if length > MAX_BODY_BYTES:
            self.close_connection = True
            self._text(HTTPStatus.REQUEST_ENTITY_TOO_LARGE, f"request body over {MAX_BODY_BYTES} bytes")
            return False
        while length > 0:
            chunk = self.rfile.read(min(length, 65536))
            if not chunk:
                self.close_connection = True
                self._text(HTTPStatus.BAD_REQUEST, "the request body ended before Content-Length")
                return False
            length -= len(chunk)
        return True

    def _dispatch(self) -> None:
        try:
            refusal = self._host_refusal()
            if refusal is None and self.command in STATE_CHANGING:
                refusal = self._state_change_refusal()
            if not self._drain_body():
                return
            if refusal is not None:
                self._text(HTTPStatus.FORBIDDEN, refusal)
                return
            if self.command == "GET":
                self._get()
            elif self.command == "POST":
                self._post()
            else:
                self._send(HTTPStatus.METHOD_NOT_ALLOWED, b"method not allowed\n",
                           "text/plain; charset=utf-8", {"Allow": "GET, POST"})
        except (BrokenPipeError, ConnectionResetError, TimeoutError):
            self.close_connection = True
        except Exception as err:  # noqa: BLE001 - a bug: count it, answer, keep serving
            self.server.internal_errors.append(f"{type(err).__name__}: {err}")
            self.close_connection = True
            self._text(HTTPStatus.INTERNAL_SERVER_ERROR, "internal error")

    do_GET = do_POST = do_PUT = do_DELETE = do_PATCH = do_OPTIONS = _dispatch  # noqa: N815

    # -- routes ------------------------------------------------------------------------
    def _route(self) -> tuple[str, dict[str, list[str]]]:
        """The request's path and query (split by hand: ``urlparse`` raises on some
        request targets, and the target is never a full URL here)."""
        target = self.path.split("#", 1)[0]
        path, _, query = target.partition("?")
        return path, parse_qs(query)

    def _live(self, query: dict[str, list[str]]) -> LiveView | None:
        """The sensor named by ``sensor=K`` (default 0), or None (after a 404) when none is."""
        lives = self.server.lives
        text = query.get("sensor", ["0"])[0]
        if text.isascii() and text.isdigit() and len(text) <= 4 and int(text) < len(lives):
            return lives[int(text)]
        self._text(HTTPStatus.NOT_FOUND, f"no sensor {text[:20]!r}; sensors 0..{len(lives) - 1}")
        return None

    def _json(self, status: int, value: object) -> None:
        self._send(status, json.dumps(value).encode(), "application/json")

    def _get(self) -> None:
        path, query = self._route()
        if path in ("/", "/index.html"):
            nonce = secrets.token_urlsafe(16)
            csp = (f"default-src 'none'; script-src 'nonce-{nonce}'; style-src 'nonce-{nonce}'; "
                   "img-src 'self' blob:; connect-src 'self'; base-uri 'none'; form-action 'none'; "
                   "frame-ancestors 'none'")
            titles = [live.title for live in self.server.lives]
            self._send(HTTPStatus.OK, page_html(titles, self.server.token, nonce).encode(),
                       "text/html; charset=utf-8", {"Content-Security-Policy": csp})
        elif path == "/frame.jpg":
            live = self._live(query)
            if live is None:
                return
            try:
                after = int(query.get("after", ["-1"])[0])
            except ValueError:
                after = -1
            wait = FRAME_WAIT_S if live.latest() is not None else FIRST_FRAME_WAIT_S
            published = live.wait_frame(after, wait)
            if published is None:
                self._text(HTTPStatus.SERVICE_UNAVAILABLE, live.error or "no frame yet")
                return
            self._send(HTTPStatus.OK, published.jpeg, "image/jpeg",
                       {"X-Frame-Seq": str(published.seq)})
            live.note_served(published)
        elif path == "/stats.json":
            live = self._live(query)
            if live is not None:
                self._json(HTTPStatus.OK, live.stats())
        else:
            self._text(HTTPStatus.NOT_FOUND, "not found")

    def _post(self) -> None:
        path, query = self._route()
        if path not in ("/reset", "/snapshot", "/record/start", "/record/stop"):
            self._text(HTTPStatus.NOT_FOUND, "not found")
            return
        live = self._live(query)
        if live is None:
            return
        try:
            if path == "/reset":
                live.reset_reference()
                self._text(HTTPStatus.OK, "reference reset")
            elif path == "/snapshot":
                files = live.snapshot()
                self._json(HTTPStatus.OK, {"files": [str(f) for f in files]})
            elif path == "/record/start":
                self._json(HTTPStatus.OK, {"path": str(live.start_recording()), "active": True})
            else:
                done = live.stop_recording()
                self._json(HTTPStatus.OK, {"path": str(done[0]) if done else None,
                                           "frames": done[1] if done else 0, "active": False})
        except ThinTactError as err:  # no frame yet, already recording, output not writable
            self._json(HTTPStatus.CONFLICT, {"error": str(err)})


class _Server(ThreadingHTTPServer):
    daemon_threads = True
    lives: list[LiveView]

    def __init__(self, port: int) -> None:
        super().__init__((LOOPBACK, port), _Handler)
        bound = self.server_address[1]
        self.hosts = allowed_hosts(bound)
        self.origins = frozenset(f"http://{host}" for host in self.hosts)
        self.token = secrets.token_urlsafe(32)
        self.internal_errors: list[str] = []


class ViewerServer:
    """Serves one or several :class:`LiveView` on ``http://127.0.0.1:PORT/``.

    The port is bound when the server is made (so a busy port fails before the sensor is
    opened); :meth:`start` starts the frame loop and the serving thread. Requests must be
    addressed to this server and state-changing ones must carry :attr:`token` (see the
    module docstring).

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
        self.lives: list[LiveView] = []

    @property
    def live(self) -> LiveView | None:
        """The first (or only) sensor's view, None before :meth:`start`."""
        return self.lives[0] if self.lives else None

    @property
    def port(self) -> int:
        """The bound TCP port."""
        return int(self._httpd.server_address[1])

    @property
    def url(self) -> str:
        """The page's address."""
        return f"http://{LOOPBACK}:{self.port}/"

    @property
    def token(self) -> str:
        """The per-server secret that state-changing requests carry in :data:`TOKEN_HEADER`."""
        return self._httpd.token

    @property
    def internal_errors(self) -> list[str]:
        """Requests that hit a bug (answered 500); empty in a healthy server."""
        return list(self._httpd.internal_errors)

    def start(self, lives: LiveView | Sequence[LiveView]) -> ViewerServer:
        """Start the frame loop of each view and serve them, in that order on the page."""
        views = [lives] if isinstance(lives, LiveView) else list(lives)
        if not views:
            raise ThinTactError("the viewer needs at least one sensor")
        self.lives = self._httpd.lives = views
        for live in views:
            live.start()
        self._thread.start()
        return self

    def stop(self) -> None:
        """Stop serving, then stop every frame loop (closing running recordings). Safe to
        call twice."""
        if self._thread.is_alive():
            self._httpd.shutdown()
        self._httpd.server_close()
        for live in self.lives:
            live.stop()

    def __enter__(self) -> ViewerServer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()
