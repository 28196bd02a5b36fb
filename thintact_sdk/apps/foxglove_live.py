"""Live Foxglove WebSocket server: a sensor's frames on the topics of its MCAP log.

:class:`LiveServer` publishes exactly what :class:`~thintact_sdk.formats.mcap.McapLogWriter`
writes (the same topics, ``ros2msg`` schemas from :mod:`thintact_sdk.formats.mcap.schemas`,
CDR messages built by :func:`~thintact_sdk.formats.mcap.writer.raw_messages` and
:func:`~thintact_sdk.formats.mcap.writer.tactile_messages`, wall-time stamps) through the
``foxglove-sdk`` WebSocket server, so Foxglove and Lichtblick show a running sensor with the
layout of a recorded log (``thintact live PROFILE``; install with
``pip install 'thintact-sdk[live]'``). The messages are those of the Foxglove WebSocket
protocol v1 (ws-protocol); ``foxglove-sdk`` names the subprotocol ``foxglove.sdk.v1`` and
accepts no other name in the handshake, so a client must offer that name (current
Foxglove and Lichtblick do; clients that offer only ``foxglove.websocket.v1`` are refused).

::

    with thintact.open("virtual-finger") as finger, LiveServer(finger.profile) as live:
        print(live.url)
        while True:
            raw = finger.read_raw()
            live.publish(raw, finger.process(raw))
"""

from __future__ import annotations

import time
from typing import Any

from thintact_sdk.errors import ThinTactError
from thintact_sdk.formats.mcap import images, schemas
from thintact_sdk.formats.mcap.writer import Messages, raw_messages, tactile_messages
from thintact_sdk.formats.profiles import Profile
from thintact_sdk.frames import RawFrame, TactileFrame

DEFAULT_HOST = "127.0.0.1"
DEFAULT_PORT = 8765
SUBPROTOCOL = "foxglove.sdk.v1"
"""The WebSocket subprotocol the server selects (ws-protocol v1 messages under its SDK name)."""
LEGACY_SUBPROTOCOL = "foxglove.websocket.v1"
"""The same protocol's original name, which ``foxglove-sdk`` servers do not accept."""


class LiveServerError(ThinTactError):
    """The live server cannot start (``foxglove-sdk`` missing, port taken, bad host)."""


class LiveServer:
    """Publishes a sensor's raw and tactile frames to Foxglove WebSocket clients.

    Parameters
    ----------
    profile
        The sensor's profile; its name is every header's ``frame_id``.
    host
        Address to bind (default ``127.0.0.1``: this machine only; ``0.0.0.0`` serves the
        network, without authentication).
    port
        TCP port (default 8765; 0 picks a free one, see :attr:`port`).
    image_encoding, msb_align, raw_preview
        As for :class:`~thintact_sdk.formats.mcap.McapLogWriter`.

    Every topic of :data:`~thintact_sdk.formats.mcap.TOPICS` is advertised when the server
    starts; a message goes only to clients subscribed to its topic. Stamps are wall time:
    capture time (``time.monotonic_ns``) plus ``wall_minus_clock_ns``, taken once at start.

    Raises
    ------
    LiveServerError
        When ``foxglove-sdk`` is not installed or the server cannot bind.
    """

    def __init__(self, profile: Profile, *, host: str = DEFAULT_HOST, port: int = DEFAULT_PORT,
                 image_encoding: str = "rgb8", msb_align: bool = True,
                 raw_preview: bool | None = None) -> None:
        try:
            import foxglove
        except ImportError:
            raise LiveServerError(
                "the live server needs foxglove-sdk: pip install 'thintact-sdk[live]'") from None
        from mcap_ros2._dynamic import serialize_dynamic

        images.check_reconstruction_encoding(image_encoding)
        if not 0 <= int(port) <= 65535:
            raise LiveServerError(f"port must be 0..65535, not {port}")
        self.profile = profile
        self.frame_id = profile.name
        self.image_encoding = image_encoding
        self.msb_align = msb_align
        self.raw_preview = raw_preview
        self.wall_minus_clock_ns = time.time_ns() - time.monotonic_ns()
        self.host = host
        self.published = 0
        """Messages handed to the server (sent to each subscribed client)."""
        self._context = foxglove.Context()
        self._encoders: dict[str, Any] = {}
        self._channels: dict[str, Any] = {}
        for topic in schemas.TOPICS:
            text = schemas.DEFINITIONS[topic.schema]
            if topic.schema not in self._encoders:
                self._encoders[topic.schema] = serialize_dynamic(topic.schema, text)[topic.schema]
            self._channels[topic.name] = foxglove.Channel(
                topic.name, message_encoding="cdr", context=self._context,
                schema=foxglove.Schema(name=topic.schema, encoding="ros2msg",
                                       data=text.encode()))
        try:
            self._server: Any = foxglove.start_server(
                name=f"thintact {profile.name}", host=host, port=int(port),
                context=self._context)
        except Exception as err:  # the Rust core raises its own error types
            raise LiveServerError(f"cannot start the live server on {host}:{port}: {err}") from None
        self.port: int = int(self._server.port)
        """The bound TCP port."""

    @property
    def url(self) -> str:
        """``ws://host:port`` to open in Foxglove (Open connection → Foxglove WebSocket)."""
        return f"ws://{self.host}:{self.port}"

    def _send(self, messages: Messages, stamp: int) -> None:
        for topic, msg in messages:
            data = self._encoders[topic.schema](msg)
            self._channels[topic.name].log(bytes(data), log_time=int(stamp))
            self.published += 1

    def publish_raw(self, raw: RawFrame) -> None:
        """Publish ``/thintact/raw`` (and ``/thintact/raw_preview``) of a camera frame."""
        stamp = raw.timestamp_ns + self.wall_minus_clock_ns
        messages, _ = raw_messages(raw, self.frame_id, stamp, msb_align=self.msb_align,
                                   preview=self.raw_preview)
        self._send(messages, stamp)

    def publish_tactile(self, frame: TactileFrame) -> None:
        """Publish a tactile frame's topics (image, depth, markers, contact, force, slip)."""
        stamp = frame.timestamp_ns + self.wall_minus_clock_ns
        self._send(tactile_messages(frame, self.frame_id, stamp, self.image_encoding), stamp)

    def publish(self, raw: RawFrame | None, frame: TactileFrame | None) -> None:
        """Publish a camera frame and/or its tactile frame."""
        if raw is not None:
            self.publish_raw(raw)
        if frame is not None:
            self.publish_tactile(frame)

    def close(self) -> None:
        """Stop the server (clients are disconnected). Safe to call twice."""
        server, self._server = self._server, None
        if server is not None:
            server.stop()

    def __enter__(self) -> LiveServer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
