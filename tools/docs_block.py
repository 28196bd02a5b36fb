"""Write a measuring tool's text into a markdown file between its two marker comments
(appended at the end when the markers are absent), so the docs carry what the tool measured."""

from __future__ import annotations

from pathlib import Path


def write_block(path: Path, opening: str, closing: str, text: str) -> None:
    """Replace what lies between ``opening`` and ``closing`` in ``path`` by ``text``."""
    doc = path.read_text(encoding="utf-8")
    block = f"{opening}\n{text}{closing}"
    if opening in doc and closing in doc:
        doc = doc[: doc.index(opening)] + block + doc[doc.index(closing) + len(closing):]
    else:
        doc = doc.rstrip("\n") + "\n\n" + block + "\n"
    path.write_text(doc, encoding="utf-8")


def host_line() -> str:
    """``"<CPU model>, <n> cores"`` of this host, for the line every measured table carries."""
    from thintact_sdk.host.machine import host_capabilities

    caps = host_capabilities()
    return f"{caps.cpu_model}, {caps.cores} cores"
