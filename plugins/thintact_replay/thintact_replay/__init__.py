"""ThinTact replay camera (plugin ``replay``): plays recordings through the Camera API.

Camera component ``replay``: ``factory(profile, settings)`` →
:class:`thintact_replay.camera.ReplayCamera`; see that module for the settings and the
end-of-recording signal (:class:`thintact_replay.camera.EndOfRecording`).
"""

from __future__ import annotations

from typing import Any

from thintact_replay.camera import EndOfRecording, ReplayCamera
from thintact_sdk import Component, hookimpl
from thintact_sdk.profile import Profile

__all__ = ["EndOfRecording", "ReplayCamera"]


def _create(profile: Profile, settings: dict[str, Any] | None = None) -> ReplayCamera:
    return ReplayCamera(profile, settings or {})


@hookimpl
def thintact_cameras() -> list[Component]:
    return [
        Component(
            "replay",
            _create,
            "plays a thintact-recording/1 directory (recorded rate or as fast as possible)",
        )
    ]
