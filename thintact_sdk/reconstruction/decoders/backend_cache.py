"""Per-host, per-operator record of measured backends in the user's cache directory.

One JSON file, ``<cache dir>/decoder-backends.json``, maps ``<host fingerprint>|<decoder and
operator shape>`` to the measured times and accuracy costs of every candidate backend, so
the next decoder of that shape on that host is built on the chosen backend without measuring.
"""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path
from typing import Any

CACHE_FILE = "decoder-backends.json"


def cache_dir() -> Path:
    """``$THINTACT_CACHE_DIR``, else ``$XDG_CACHE_HOME/thintact``, else ``~/.cache/thintact``."""
    explicit = os.environ.get("THINTACT_CACHE_DIR")
    if explicit:
        return Path(explicit).expanduser()
    xdg = os.environ.get("XDG_CACHE_HOME")
    base = Path(xdg).expanduser() if xdg else Path.home() / ".cache"
    return base / "thintact"


class BackendCache:
    """Read and write measured backend records (JSON objects) by key.

    Parameters
    ----------
    path
        The JSON file (default :func:`cache_dir` / ``decoder-backends.json``).
    """

    def __init__(self, path: Path | None = None) -> None:
        self.path = path or cache_dir() / CACHE_FILE

    def _read_all(self) -> dict[str, Any]:
        try:
            data = json.loads(self.path.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            return {}  # absent or unreadable: measure again and rewrite
        return data if isinstance(data, dict) else {}

    def get(self, key: str) -> dict[str, Any] | None:
        """The record stored under ``key``, or None."""
        entry = self._read_all().get(key)
        return entry if isinstance(entry, dict) else None

    def put(self, key: str, record: dict[str, Any]) -> None:
        """Store ``record`` under ``key`` (atomic replace; an unwritable cache is skipped)."""
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            data = self._read_all()
            data[key] = record
            fd, tmp = tempfile.mkstemp(dir=self.path.parent, prefix=".backends-", suffix=".json")
            with os.fdopen(fd, "w", encoding="utf-8") as f:
                json.dump(data, f, indent=1, sort_keys=True)
            os.replace(tmp, self.path)
        except OSError:
            pass
