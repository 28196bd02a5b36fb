"""Plugin discovery: the SDK's own plugins, a throw-away third-party plugin installed with
pip, and a broken plugin that must not break the others."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from thintact_sdk.device.registry import get_registry

THIRD_PARTY = {
    "pyproject.toml": """
        [build-system]
        requires = ["setuptools>=61"]
        build-backend = "setuptools.build_meta"
        [project]
        name = "acme-thintact-camera"
        version = "1.2.3"
        [project.entry-points.thintact]
        acme = "acme_thintact_camera"
        broken = "acme_broken_plugin"
        [tool.setuptools]
        packages = ["acme_thintact_camera", "acme_broken_plugin"]
    """,
    "acme_thintact_camera/__init__.py": """
        import time
        import numpy as np
        from thintact_sdk import Component, hookimpl
        from thintact_sdk.frames import RawFrame
        from thintact_sdk.interfaces import Camera, CameraCapabilities

        class AcmeCamera(Camera):
            name = "acme"
            def __init__(self, profile, settings):
                self.h, self.w = 2 * profile.sensor.rows, 2 * profile.sensor.cols
                self.level = int(settings.get("level", 100))
                self.n = 0
            def open(self): self._is_open = True
            def close(self): self._is_open = False
            def capabilities(self):
                return CameraCapabilities(self.w, self.h, ["BayerRG12"], "BayerRG12")
            def read(self, timeout_s=2.0):
                self.n += 1
                return RawFrame(np.full((self.h, self.w), self.level, np.uint16), time.monotonic_ns(), self.n)

        @hookimpl
        def thintact_cameras():
            return [Component("acme-cam", AcmeCamera, "ACME test camera")]
    """,
    "acme_broken_plugin/__init__.py": """
        raise ImportError("acme driver library libacme.so not found")
    """,
}

USE_IT = """
import json, sys
from thintact_sdk.device.registry import get_registry
from thintact_sdk.formats.profiles import load_profile
from thintact_sdk.pixels.bayer import bin_bayer
reg = get_registry()
cam = reg.create("camera", "acme-cam", load_profile("virtual-mini"), {"level": 321})
with cam:
    frame = cam.read()
m = bin_bayer(frame.data, "RGGB")
print(json.dumps({"shape": list(m.shape), "value": float(m.mean()),
                  "broken_error": reg.plugins["broken"].error}))
"""


def test_sdk_plugins_are_discovered() -> None:
    reg = get_registry()
    failed = {n: p.error for n, p in reg.plugins.items() if p.error}
    assert not failed, failed
    assert reg.plugins, "no plugin found in entry-point group 'thintact'"
    for info in reg.plugins.values():
        assert info.distribution, f"{info.name} is not an installed distribution"


@pytest.mark.timeout(300)
def test_third_party_plugin_installed_with_pip_is_discovered_and_used(tmp_path: Path) -> None:
    src = tmp_path / "src"
    for rel, text in THIRD_PARTY.items():
        p = src / rel
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(textwrap.dedent(text))
    target = tmp_path / "site"
    subprocess.run(
        [sys.executable, "-m", "pip", "install", "-q", "--no-deps",
         "--target", str(target), str(src)],
        check=True, capture_output=True, text=True, timeout=240,
    )
    env = dict(os.environ, PYTHONPATH=str(target))
    listing = subprocess.run(
        [sys.executable, "-m", "thintact_sdk.apps.cli.main", "plugins", "--json"],
        capture_output=True, text=True, env=env, timeout=120,
    )
    assert listing.returncode == 0, listing.stderr
    plugins = json.loads(listing.stdout)
    assert plugins["acme"]["provides"] == {"camera": ["acme-cam"]}
    assert plugins["acme"]["distribution"] == "acme-thintact-camera"
    assert plugins["acme"]["version"] == "1.2.3"
    assert "libacme.so" in plugins["broken"]["error"]
    others = [n for n in plugins if n not in ("acme", "broken")]
    assert others and all(plugins[n]["error"] is None for n in others)

    used = subprocess.run([sys.executable, "-c", USE_IT], capture_output=True, text=True, env=env, timeout=120)
    assert used.returncode == 0, used.stderr
    out = json.loads(used.stdout)
    assert out["shape"] == [128, 160, 3] and out["value"] == 321.0
    assert "ImportError" in out["broken_error"]

    text = subprocess.run(
        [sys.executable, "-m", "thintact_sdk.apps.cli.main", "plugins"], capture_output=True, text=True, env=env,
        timeout=120,
    )
    assert "acme-cam" in text.stdout and "FAILED" in text.stdout and "libacme.so" in text.stdout


def test_unknown_component_names_alternatives() -> None:
    from thintact_sdk.errors import PluginError

    with pytest.raises(PluginError, match="no camera plugin named 'nope'"):
        get_registry().get("camera", "nope")


SHADOWING = {
    "pyproject.toml": """
        [build-system]
        requires = ["setuptools>=61"]
        build-backend = "setuptools.build_meta"
        [project]
        name = "acme-shadow-camera"
        version = "0.0.1"
        [project.entry-points.thintact]
        aaa-acme = "acme_shadow_camera"
        [tool.setuptools]
        packages = ["acme_shadow_camera"]
    """,
    "acme_shadow_camera/__init__.py": """
        from thintact_sdk import Component, hookimpl

        class ZeroCamera:
            def __init__(self, profile, settings):
                self.kind = "acme-zero"

        @hookimpl
        def thintact_cameras():
            return [Component("virtual", ZeroCamera, "a camera that takes the SDK's name")]
    """,
}

PICK_CAMERAS = """
import json
from thintact_sdk.errors import PluginError
from thintact_sdk.device.registry import get_registry
from thintact_sdk.formats.profiles import load_profile
reg = get_registry()
try:
    reg.get("camera", "virtual")
    plain = "no error"
except PluginError as err:
    plain = str(err)
acme = reg.create("camera", "aaa-acme:virtual", load_profile("virtual-mini"), {})
sdk = reg.get("camera", "virtual:virtual")
print(json.dumps({"plain": plain, "acme": acme.kind, "sdk_plugin": sdk.plugin}))
"""


@pytest.mark.timeout(300)
def test_third_party_cannot_shadow_a_builtin_camera_name(tmp_path: Path) -> None:
    """A package loaded first (entry point 'aaa-acme') that registers a camera 'virtual'
    makes the plain name ambiguous: an error naming both packages; namespaced names work."""
    src = tmp_path / "src"
    for rel, text in SHADOWING.items():
        p = src / rel
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(textwrap.dedent(text))
    target = tmp_path / "site"
    subprocess.run(
        [sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--target", str(target), str(src)],
        check=True, capture_output=True, text=True, timeout=240,
    )
    env = dict(os.environ, PYTHONPATH=str(target))
    used = subprocess.run([sys.executable, "-c", PICK_CAMERAS], capture_output=True, text=True, env=env,
                          timeout=120)
    assert used.returncode == 0, used.stderr
    out = json.loads(used.stdout)
    assert "acme-shadow-camera" in out["plain"] and "thintact-virtual" in out["plain"], out["plain"]
    assert "'aaa-acme:virtual'" in out["plain"] and "'virtual:virtual'" in out["plain"]
    assert out["acme"] == "acme-zero" and out["sdk_plugin"] == "virtual"

    rec = subprocess.run(
        [sys.executable, "-m", "thintact_sdk.apps.cli.main", "record", "--profile", "virtual-mini",
         "--frames", "1", "--out", str(tmp_path / "rec")],
        capture_output=True, text=True, env=env, timeout=120,
    )
    assert rec.returncode == 2, rec.stderr
    assert "acme-shadow-camera" in rec.stderr and "Traceback" not in rec.stderr
    assert not (tmp_path / "rec" / "recording.json").exists()


def test_collision_in_process_names_both_plugins() -> None:
    """Registering a second provider of 'virtual' in a private registry: plain name refused,
    namespaced names resolve to each provider, the collision is listed."""
    import types

    from thintact_sdk import Component, hookimpl
    from thintact_sdk.device.registry import PluginRegistry
    from thintact_sdk.errors import PluginError

    def _module(label: str) -> types.ModuleType:
        mod = types.ModuleType(f"fake_{label}")

        @hookimpl
        def thintact_cameras() -> list[Component]:
            return [Component("virtual", lambda: label, f"{label} camera")]

        mod.thintact_cameras = thintact_cameras  # type: ignore[attr-defined]
        return mod

    reg = PluginRegistry()
    reg.register(_module("sdk"), "sdk")
    reg.register(_module("acme"), "acme")
    assert reg.collisions("camera") == {"virtual": ["sdk", "acme"]}
    with pytest.raises(PluginError, match=r"'sdk:virtual' or 'acme:virtual'"):
        reg.get("camera", "virtual")
    assert reg.create("camera", "acme:virtual") == "acme"
    assert reg.create("camera", "sdk:virtual") == "sdk"
    assert "also provided by plugin 'sdk'" in (reg.plugins["acme"].error or "")
