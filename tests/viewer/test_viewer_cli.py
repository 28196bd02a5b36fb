"""``thintact view PROFILE``: one command, prints the address, serves until Ctrl-C."""

from __future__ import annotations

import json
import re
import signal
import socket
import subprocess
import sys
import time
import urllib.request

import pytest

from thintact_sdk.apps.cli.main import main


def test_view_prints_the_url_and_serves_the_sensor():
    proc = subprocess.Popen(
        [sys.executable, "-m", "thintact_sdk.apps.cli.main", "view", "virtual-finger", "--port", "0",
         "--set", "fps=0", "--duration", "300"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        line = proc.stdout.readline()
        match = re.search(r"viewing virtual-finger at (http://127\.0\.0\.1:\d+/)", line)
        assert match, line + proc.stderr.read()
        url = match.group(1)
        deadline = time.monotonic() + 60
        stats = {}
        while time.monotonic() < deadline and not stats.get("frame_id"):
            with urllib.request.urlopen(url + "stats.json", timeout=10) as r:
                stats = json.loads(r.read())
            time.sleep(0.2)
        assert stats["frame_id"] is not None and stats["error"] is None
        proc.send_signal(signal.SIGINT)  # Ctrl-C: the normal way to stop
        out, err = proc.communicate(timeout=90)
    finally:
        proc.kill()
    assert proc.returncode == 0, err
    assert "stopped: sensor" in out and "Traceback" not in err


def test_view_bad_input_is_a_one_line_error(capsys):
    assert main(["view", "no-such-profile", "--port", "0"]) == 2
    assert "no-such-profile" in capsys.readouterr().err
    assert main(["view", "virtual-finger", "--port", "70000"]) == 2
    assert "--port: must be an integer between 0 and 65535" in capsys.readouterr().err
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        assert main(["view", "virtual-finger", "--port", str(port), "--duration", "1"]) == 2
    assert f"cannot serve the viewer on 127.0.0.1:{port}" in capsys.readouterr().err


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_view_stops_on_a_signal_even_where_sigint_was_ignored(sig):
    """Issue 30: started as a script's background job (SIGINT ignored on entry), the viewer
    still stops on Ctrl-C; SIGTERM stops it the same way. Exit 0, the sensor closed."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "thintact_sdk.apps.cli.main", "view", "virtual-finger", "--port", "0",
         "--set", "fps=0"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_IGN))
    try:
        line = proc.stdout.readline()
        assert "viewing virtual-finger at http://127.0.0.1:" in line, line + proc.stderr.read()
        proc.send_signal(sig)
        out, err = proc.communicate(timeout=90)  # a bound on a hang, not a performance figure
    finally:
        proc.kill()
    assert proc.returncode == 0, err
    assert "stopped: sensor" in out and "Traceback" not in err


SLOW_OPEN = """
import sys, time
import thintact_sdk, thintact_sdk.apps.cli.main as cli
real_open = thintact_sdk.open
def slow_open(*args, **kwargs):
    print("opening", flush=True)
    time.sleep(120)  # a camera that takes long to open
    return real_open(*args, **kwargs)
thintact_sdk.open = slow_open
sys.exit(cli.main(["view", "virtual-finger", "--port", "0"]))
"""


def test_view_stops_on_a_signal_while_the_sensor_opens():
    proc = subprocess.Popen([sys.executable, "-c", SLOW_OPEN], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline().strip() == "opening", proc.stderr.read()
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=60)  # a bound on a hang (the open sleeps 120 s)
    finally:
        proc.kill()
    assert proc.returncode == 0, err
    assert err.strip() == "stopped before the viewer started" and "viewing" not in out


@pytest.mark.parametrize("value", ["nan", "inf", "-inf", "-1", "abc"])
def test_view_refuses_a_bad_duration_in_one_line(value, capsys):
    assert main(["view", "virtual-finger", "--port", "0", "--duration", value]) == 2
    err = capsys.readouterr().err
    assert "--duration" in err and len(err.strip().splitlines()) == 1


def test_view_refuses_a_bad_reference_frame_count(capsys):
    assert main(["view", "virtual-finger", "--port", "0", "--reference-frames", "0"]) == 2
    assert "--reference-frames" in capsys.readouterr().err


def test_view_shows_two_sensors_and_their_buttons_write_under_out(tmp_path):
    """Issue 33: ``thintact view P1 P2 --out DIR``: one panel group per sensor; snapshot and
    record (with the page's token) write under DIR; Ctrl-C reports each sensor."""
    out_dir = tmp_path / "viewer-out"
    proc = subprocess.Popen(
        [sys.executable, "-m", "thintact_sdk.apps.cli.main", "view", "virtual-finger", "virtual-finger",
         "--port", "0", "--set", "fps=0", "--out", str(out_dir)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=tmp_path)
    try:
        line = proc.stdout.readline()
        match = re.search(r"viewing virtual-finger, virtual-finger at (http://127\.0\.0\.1:\d+/)", line)
        assert match, line + proc.stderr.read()
        url = match.group(1)
        with urllib.request.urlopen(url, timeout=30) as r:
            page = r.read().decode()
        token = re.search(r'<meta name="thintact-token" content="([^"]+)">', page).group(1)
        assert 'id="live-1"' in page and "thintact view virtual-finger-1" in page

        def stats(k):
            with urllib.request.urlopen(f"{url}stats.json?sensor={k}", timeout=30) as r:
                return json.loads(r.read())

        def post(path):
            req = urllib.request.Request(url + path, data=b"", headers={"X-ThinTact-Token": token})
            with urllib.request.urlopen(req, timeout=30) as r:
                return json.loads(r.read())

        deadline = time.monotonic() + 120  # a bound on a hang while the decoders load
        while time.monotonic() < deadline and not all(stats(k)["frame_id"] for k in (0, 1)):
            time.sleep(0.2)
        assert all(stats(k)["frame_id"] for k in (0, 1)), [stats(k) for k in (0, 1)]
        files = post("snapshot?sensor=1")["files"]
        started = post("record/start?sensor=0")["path"]
        while time.monotonic() < deadline and stats(0)["recording"]["frames"] < 2:
            time.sleep(0.2)
        stopped = post("record/stop?sensor=0")
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=90)
    finally:
        proc.kill()
    assert proc.returncode == 0, err
    assert all(f.startswith(str(out_dir / "snapshot-virtual-finger-1-")) for f in files) and len(files) == 2
    assert stopped["path"] == started and stopped["frames"] >= 2
    assert started.startswith(str(out_dir / "recording-virtual-finger-0-"))
    assert "stopped virtual-finger-0:" in out and "stopped virtual-finger-1:" in out
    assert "Traceback" not in err
    from thintact_sdk.formats.recording import Recording

    assert len(Recording(started)) == stopped["frames"]
