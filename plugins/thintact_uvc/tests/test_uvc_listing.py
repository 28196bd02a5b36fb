"""The uvc plugin's section of ``thintact devices`` (its device lister)."""

from __future__ import annotations

import argparse

import thintact_uvc.listing as listing


def test_the_lister_is_registered_and_lists_nodes(monkeypatch) -> None:
    from thintact_sdk.device.registry import get_registry

    assert "uvc" in get_registry().components("device_lister")

    def fake_glob(pattern: str) -> list[str]:
        return {"/dev/video*": ["/dev/video2", "/dev/video0"],
                "/dev/v4l/by-id/*": []}.get(pattern, [])

    monkeypatch.setattr(listing.glob, "glob", fake_glob)
    parser = argparse.ArgumentParser()
    lister = get_registry().create("device_lister", "uvc", parser)
    data, lines = lister(parser.parse_args([]))
    assert [d["path"] for d in data] == ["/dev/video0", "/dev/video2"]
    assert lines[0] == "UVC / V4L2" and lines[1].startswith("  /dev/video0")


def test_no_node_is_an_empty_section(monkeypatch) -> None:
    monkeypatch.setattr(listing.glob, "glob", lambda pattern: [])
    assert listing.video_nodes() == []
    assert listing.section_lines([]) == ["UVC / V4L2", "  no /dev/video* device"]
