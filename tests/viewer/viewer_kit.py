"""Shared helpers of the viewer tests: a sensor-less LiveView that counts state changes, and
a raw-socket HTTP client that sends exactly the bytes a test asks for."""

from __future__ import annotations

import socket
import threading
from types import SimpleNamespace
from typing import Any

from thintact_sdk.apps.viewer import LiveView
from thintact_sdk.errors import EndOfStreamError


class _EndedSensor:
    """A sensor whose source has already ended: the frame loop stops at once."""

    profile = SimpleNamespace(name="fake-sensor")

    def read_raw(self) -> Any:
        raise EndOfStreamError("the fake source has no frames")


class CountingLive(LiveView):
    """A LiveView without a sensor that counts state-changing calls (reset, snapshot, record
    start and stop) in :attr:`changes` instead of acting on them."""

    def __init__(self) -> None:
        super().__init__(_EndedSensor(), title="fake viewer", out="/nonexistent/never-written")  # type: ignore[arg-type]
        self.changes = 0
        self._count_lock = threading.Lock()

    def _count(self) -> None:
        with self._count_lock:
            self.changes += 1

    def reset_reference(self) -> None:
        self._count()

    def snapshot(self) -> Any:
        self._count()
        return []

    def start_recording(self) -> Any:
        self._count()
        return "/nonexistent/never-written"

    def stop_recording(self) -> Any:
        self._count()
        return None


def raw_request(port: int, request: bytes, timeout_s: float = 20.0) -> tuple[int | None, bytes]:
    """Send ``request`` as it is to 127.0.0.1:``port``, half-close, read the reply.

    Returns the status code (None when the server closed without a status line) and the
    whole reply.
    """
    with socket.create_connection(("127.0.0.1", port), timeout=timeout_s) as sock:
        try:
            sock.sendall(request)
            sock.shutdown(socket.SHUT_WR)
        except OSError:
            pass  # the server answered (and closed) before reading everything
        reply = b""
        try:
            while chunk := sock.recv(65536):
                reply += chunk
        except ConnectionResetError:
            pass
    head = reply.split(b"\r\n", 1)[0].split()
    status = int(head[1]) if len(head) >= 2 and head[0].startswith(b"HTTP/") and head[1].isdigit() else None
    return status, reply


def http(port: int, method: str, path: str, headers: dict[str, str] | None = None,
         body: bytes = b"", host: str | None = "default") -> tuple[int | None, bytes]:
    """A well-formed HTTP/1.1 request; ``host`` "default" is ``127.0.0.1:port``, None none."""
    lines = [f"{method} {path} HTTP/1.1"]
    if host is not None:
        lines.append(f"Host: {f'127.0.0.1:{port}' if host == 'default' else host}")
    for key, value in (headers or {}).items():
        lines.append(f"{key}: {value}")
    if body or method in ("POST", "PUT", "PATCH"):
        lines.append(f"Content-Length: {len(body)}")
    lines.append("Connection: close")
    return raw_request(port, ("\r\n".join(lines) + "\r\n\r\n").encode("latin-1") + body)


class HeadlessChromium:
    """Headless Chromium driven over the DevTools protocol on a pipe (``--remote-debugging-pipe``:
    JSON messages separated by NUL on file descriptors 3 and 4; no extra package, no port).

    ``evaluate(url, expression)`` opens ``url`` in a new tab, waits for its load event, and
    returns the value of the JavaScript ``expression`` (promises are awaited).
    """

    def __init__(self, browser: str, profile_dir: str) -> None:
        import fcntl
        import os
        import subprocess

        def high(fd: int) -> int:  # away from 3 and 4, so that wiring them cannot clobber
            moved = fcntl.fcntl(fd, fcntl.F_DUPFD_CLOEXEC, 10)
            os.close(fd)
            return moved

        to_child_r, self._to_child = (high(fd) for fd in os.pipe())
        self._from_child, from_child_w = (high(fd) for fd in os.pipe())

        def wire() -> None:  # in the child: the pipe ends become fds 3 and 4 (inheritable)
            os.dup2(to_child_r, 3)
            os.dup2(from_child_w, 4)

        self.proc = subprocess.Popen(
            [browser, "--headless", "--no-sandbox", "--disable-gpu", "--remote-debugging-pipe",
             "--disable-background-networking", "--disable-component-update", "--disable-sync",
             "--no-first-run", f"--user-data-dir={profile_dir}", "about:blank"],
            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
            preexec_fn=wire, close_fds=False)  # every other fd of ours is close-on-exec
        os.close(to_child_r)
        os.close(from_child_w)
        self._buf = b""
        self._id = 0
        self._events: list[dict[str, Any]] = []

    def _read(self, deadline: float, what: str) -> dict[str, Any]:
        """The next message from the browser."""
        import json
        import os
        import select
        import time

        while b"\0" not in self._buf:
            left = deadline - time.monotonic()
            if left <= 0:
                raise TimeoutError(f"Chromium did not send {what}")
            ready, _, _ = select.select([self._from_child], [], [], left)
            if ready:
                chunk = os.read(self._from_child, 1 << 20)
                if not chunk:
                    raise RuntimeError("Chromium exited")
                self._buf += chunk
        raw, self._buf = self._buf.split(b"\0", 1)
        return dict(json.loads(raw))

    def _call(self, method: str, params: dict[str, Any] | None = None, session: str | None = None,
              timeout_s: float = 60.0) -> dict[str, Any]:
        import json
        import os
        import time

        self._id += 1
        msg: dict[str, Any] = {"id": self._id, "method": method, "params": params or {}}
        if session:
            msg["sessionId"] = session
        os.write(self._to_child, json.dumps(msg).encode() + b"\0")
        deadline = time.monotonic() + timeout_s
        while True:
            reply = self._read(deadline, f"the answer to {method}")
            if reply.get("id") == self._id:
                if "error" in reply:
                    raise RuntimeError(f"{method}: {reply['error']}")
                return dict(reply["result"])
            self._events.append(reply)

    def _wait_event(self, method: str, session: str, timeout_s: float = 60.0) -> None:
        import time

        deadline = time.monotonic() + timeout_s
        while True:
            for k, event in enumerate(self._events):
                if event.get("method") == method and event.get("sessionId") == session:
                    del self._events[:k + 1]
                    return
            self._events.append(self._read(deadline, method))

    def evaluate(self, url: str, expression: str) -> Any:
        target = self._call("Target.createTarget", {"url": "about:blank"})["targetId"]
        session = self._call("Target.attachToTarget", {"targetId": target, "flatten": True})["sessionId"]
        self._call("Page.enable", session=session)
        self._events.clear()
        self._call("Page.navigate", {"url": url}, session)
        self._wait_event("Page.loadEventFired", session)
        result = self._call("Runtime.evaluate", {"expression": expression, "awaitPromise": True,
                                                 "returnByValue": True}, session)
        if "exceptionDetails" in result:
            raise RuntimeError(f"page script failed: {result['exceptionDetails']}")
        return result["result"].get("value")

    def close(self) -> None:
        import os

        try:
            self._call("Browser.close", timeout_s=10)
        except (RuntimeError, TimeoutError, OSError):
            pass
        try:
            self.proc.wait(timeout=10)
        except Exception:  # noqa: BLE001 - a stuck browser is killed
            self.proc.kill()
            self.proc.wait(timeout=10)
        os.close(self._to_child)
        os.close(self._from_child)


class FramesSensor:
    """A sensor with the virtual finger's profile whose frames are synthetic (no decoding):
    raw 512 × 640 Bayer mosaics and tactile frames with a pressed square, paced at about
    ``fps``. Fast enough for server tests."""

    def __init__(self, fps: float = 30.0) -> None:
        import numpy as np

        from thintact_sdk.formats.profiles import load_profile

        self.profile = load_profile("virtual-finger")
        self._rng = np.random.default_rng(0)
        self._period = 1.0 / fps
        self._n = 0
        self.resets = 0

    def read_raw(self) -> Any:
        import time

        import numpy as np

        from thintact_sdk.frames import RawFrame

        time.sleep(self._period)
        self._n += 1
        data = self._rng.integers(64, 4000, (512, 640), dtype=np.uint16)
        return RawFrame(data, time.monotonic_ns(), self._n, exposure_us=1000.0)

    def process(self, raw: Any) -> Any:
        import numpy as np

        from thintact_sdk.frames import TactileFrame

        depth = np.zeros((100, 128), np.float32)
        depth[40:60, 50:70] = 0.5
        yy, xx = np.mgrid[-2:2:5j, -3:3:5j]
        pos = np.stack([xx.ravel(), yy.ravel()], 1).astype(np.float32)
        image = np.full((100, 128, 3), 0.25, np.float32)
        image[40:60, 50:70] = 0.75
        return TactileFrame(
            image=image, depth_mm=depth, marker_positions_mm=pos,
            marker_displacements_mm=np.zeros_like(pos), contact=True, contact_area_mm2=4.0,
            timestamp_ns=raw.timestamp_ns, frame_id=raw.frame_id, shear_direction_rad=float("nan"),
            latency_ms=1.0)

    def reset_reference(self) -> None:
        self.resets += 1
