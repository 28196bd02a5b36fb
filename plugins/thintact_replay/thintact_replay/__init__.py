"""ThinTact replay camera (plugin ``replay``): plays recordings through the Camera API.

Camera component ``replay``: ``factory(profile, settings)`` →
:class:`thintact_replay.camera.ReplayCamera`; see that module for the settings and the
end-of-recording signal (:class:`thintact_replay.camera.EndOfRecording`). A ``path``
ending in ``.mcap`` plays an MCAP log instead
(:class:`thintact_replay.mcap_source.McapReplayCamera`).
"""

from __future__ import annotations

from typing import Any

from thintact_replay.camera import EndOfRecording, ReplayCamera
from thintact_replay.mcap_source import McapReplayCamera, is_mcap_path
from thintact_sdk import Component, hookimpl
from thintact_sdk.plugin_support import Profile

__all__ = ["EndOfRecording", "McapReplayCamera", "ReplayCamera"]


def _create(profile: Profile, settings: dict[str, Any] | None = None) -> ReplayCamera | McapReplayCamera:
    settings = settings or {}
    if is_mcap_path(settings.get("path")):
        return McapReplayCamera(profile, settings)
    return ReplayCamera(profile, settings)


@hookimpl
def thintact_cameras() -> list[Component]:
    return [
        Component(
            "replay",
            _create,
            "plays a thintact-recording/1 directory or an MCAP log (recorded rate or as fast as possible)",
        )
    ]
