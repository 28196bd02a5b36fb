"""The live Foxglove server: a ws-protocol v1 client on loopback subscribes to every topic and
decodes one message of each with the schema the server advertised (CDR, ros2msg).

The client offers both names of the protocol (``foxglove.sdk.v1``, ``foxglove.websocket.v1``)
as current Foxglove and Lichtblick do; foxglove-sdk selects ``foxglove.sdk.v1``."""

from __future__ import annotations

import json
import signal
import struct
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

pytest.importorskip("foxglove")
websocket = pytest.importorskip("websocket")

from mcap.records import Schema  # noqa: E402
from mcap_ros2.decoder import DecoderFactory  # noqa: E402
from mcap_testkit import PERIOD_NS, T0_NS, mini_profile, raw_frame, tactile_frame  # noqa: E402

from thintact_sdk.apps.cli.main import main  # noqa: E402
from thintact_sdk.apps.foxglove_live import (  # noqa: E402
    LEGACY_SUBPROTOCOL,
    SUBPROTOCOL,
    LiveServer,
    LiveServerError,
)
from thintact_sdk.formats.mcap import TOPICS, images, schemas  # noqa: E402

MESSAGE_DATA = 0x01


class Client:
    """A minimal Foxglove WebSocket (ws-protocol v1) client: advertise → subscribe → data."""

    def __init__(self, url: str) -> None:
        self.ws = websocket.create_connection(
            url, subprotocols=[LEGACY_SUBPROTOCOL, SUBPROTOCOL], timeout=10)
        assert self.ws.getsubprotocol() == SUBPROTOCOL
        self.server_info: dict = {}
        self.channels: dict[int, dict] = {}
        self.by_sub: dict[int, dict] = {}
        self.decoders: dict[int, object] = {}
        self.received: dict[str, list] = {}

    def _handle_json(self, msg: dict) -> None:
        if msg["op"] == "serverInfo":
            self.server_info = msg
        elif msg["op"] == "advertise":
            for ch in msg["channels"]:
                self.channels[ch["id"]] = ch

    def read_until_advertised(self, topics: set[str]) -> None:
        while {c["topic"] for c in self.channels.values()} < topics:
            frame = self.ws.recv()
            if isinstance(frame, str):
                self._handle_json(json.loads(frame))

    def subscribe_all(self) -> None:
        subs = []
        factory = DecoderFactory()
        for sub_id, (cid, ch) in enumerate(sorted(self.channels.items())):
            assert ch["encoding"] == "cdr" and ch["schemaEncoding"] == "ros2msg"
            schema = Schema(id=cid, name=ch["schemaName"], encoding="ros2msg",
                            data=ch["schema"].encode())
            self.decoders[sub_id] = factory.decoder_for("cdr", schema)
            self.by_sub[sub_id] = ch
            subs.append({"id": sub_id, "channelId": cid})
        self.ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))

    def read_one(self) -> None:
        frame = self.ws.recv()
        if isinstance(frame, str):
            self._handle_json(json.loads(frame))
            return
        assert frame[0] == MESSAGE_DATA
        sub_id, log_time = struct.unpack_from("<IQ", frame, 1)
        ch = self.by_sub[sub_id]
        decoded = self.decoders[sub_id](bytes(frame[13:]))
        self.received.setdefault(ch["topic"], []).append((log_time, ch["schemaName"], decoded))

    def close(self) -> None:
        self.ws.close()


def _publish_until(server: LiveServer, done: threading.Event) -> None:
    i = 0
    while not done.is_set() and i < 2000:
        k = i % 5
        raw = raw_frame(k)
        server.publish(raw, tactile_frame(k, with_force=True))
        i += 1
        time.sleep(0.01)


def test_a_websocket_client_decodes_every_topic_on_loopback():
    topics = {t.name for t in TOPICS}
    with LiveServer(mini_profile(), port=0) as server:
        assert server.host == "127.0.0.1" and server.url == f"ws://127.0.0.1:{server.port}"
        client = Client(server.url)
        try:
            client.read_until_advertised(topics)
            assert {c["topic"]: c["schemaName"] for c in client.channels.values()} == {
                t.name: t.schema for t in TOPICS}
            for ch in client.channels.values():
                assert ch["schema"] == schemas.DEFINITIONS[ch["schemaName"]]  # shared, not copied
            client.subscribe_all()
            done = threading.Event()
            pub = threading.Thread(target=_publish_until, args=(server, done), daemon=True)
            pub.start()
            try:
                while set(client.received) < topics:
                    client.read_one()
            finally:
                done.set()
                pub.join()
        finally:
            client.close()
    offset = server.wall_minus_clock_ns
    for topic, msgs in client.received.items():
        log_time, _, msg = msgs[0]
        assert log_time == images.stamp_ns(msg.header)
        k = (log_time - offset - T0_NS) // PERIOD_NS
        assert log_time == T0_NS + k * PERIOD_NS + offset and 0 <= k < 5, topic
        assert msg.header.frame_id == "virtual-mini"
    _, _, raw = client.received["/thintact/raw"][0]
    k = (images.stamp_ns(raw.header) - offset - T0_NS) // PERIOD_NS
    assert raw.encoding == "bayer_rggb16"
    np.testing.assert_array_equal(
        np.frombuffer(bytes(raw.data), "<u2").reshape(256, 320) >> 4, raw_frame(k).data)
    _, _, prev = client.received["/thintact/raw_preview"][0]
    assert (prev.encoding, prev.height, prev.width) == ("rgb8", 128, 160)
    _, _, depth = client.received["/thintact/depth"][0]
    k = (images.stamp_ns(depth.header) - offset - T0_NS) // PERIOD_NS
    np.testing.assert_array_equal(np.frombuffer(bytes(depth.data), "<f4").reshape(50, 64),
                                  tactile_frame(k).depth_mm)
    _, _, contact = client.received["/thintact/contact"][0]
    assert contact.camera_frame_id == 100 + (
        images.stamp_ns(contact.header) - offset - T0_NS) // PERIOD_NS
    _, _, slip = client.received["/thintact/slip"][0]
    k = (images.stamp_ns(slip.header) - offset - T0_NS) // PERIOD_NS
    assert slip.slip_ratio == pytest.approx(0.1 * k)
    _, _, force = client.received["/thintact/force"][0]
    k = (images.stamp_ns(force.header) - offset - T0_NS) // PERIOD_NS
    assert (force.wrench.force.x, force.wrench.force.z) == pytest.approx((0.1 * k, 1.0 + k))


def test_a_taken_port_is_one_clear_error():
    with LiveServer(mini_profile(), port=0) as first:
        with pytest.raises(LiveServerError, match=f"cannot start the live server on 127.0.0.1:{first.port}"):
            LiveServer(mini_profile(), port=first.port)
    with pytest.raises(LiveServerError, match="port must be 0..65535"):
        LiveServer(mini_profile(), port=70000)


def test_live_command_streams_a_virtual_sensor_and_refuses_bad_options(capsys):
    assert main(["live", "virtual-finger", "--port", "0", "--frames", "2", "--set", "fps=0"]) == 0
    out = capsys.readouterr().out
    assert "streaming virtual-finger on ws://127.0.0.1:" in out
    assert "stopped after 2 frame(s)" in out
    assert main(["live", "virtual-finger", "--port", "70000"]) == 2
    assert "--port: must be an integer between 0 and 65535" in capsys.readouterr().err


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_live_stops_on_a_signal_even_where_sigint_was_ignored(sig):
    """Like the viewer: started with SIGINT ignored (a script's background job), `thintact
    live` still stops on Ctrl-C or SIGTERM, closes the sensor and exits 0."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "thintact_sdk.apps.cli.main", "live", "virtual-finger", "--port", "0",
         "--set", "fps=0"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_IGN))
    try:
        line = proc.stdout.readline()
        assert "streaming virtual-finger on ws://127.0.0.1:" in line, line + proc.stderr.read()
        proc.send_signal(sig)
        out, err = proc.communicate(timeout=90)  # a bound on a hang, not a performance figure
    finally:
        proc.kill()
    assert proc.returncode == 0, err
    assert "stopped after" in out and "Traceback" not in err

