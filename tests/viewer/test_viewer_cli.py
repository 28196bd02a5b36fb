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

from thintact_sdk.cli.main import main


def test_view_prints_the_url_and_serves_the_sensor():
    proc = subprocess.Popen(
        [sys.executable, "-m", "thintact_sdk.cli.main", "view", "virtual-finger", "--port", "0",
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
    assert "--port must be 0..65535" in capsys.readouterr().err
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        assert main(["view", "virtual-finger", "--port", str(port), "--duration", "1"]) == 2
    assert f"cannot serve the viewer on 127.0.0.1:{port}" in capsys.readouterr().err
