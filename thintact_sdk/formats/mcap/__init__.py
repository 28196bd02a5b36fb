"""MCAP logs with ROS 2 message encodings (``thintact record --format mcap``).

:class:`McapLogWriter` writes one sensor's raw and tactile frames; :class:`McapLog`
reads them back, also from a file cut short by a killed writer or a full disk. Topics,
message types and metadata: :mod:`thintact_sdk.formats.mcap.schemas` and docs/logging.md.
"""

from __future__ import annotations

from thintact_sdk.formats.mcap.reader import LogMessage, McapLog
from thintact_sdk.formats.mcap.schemas import LOG_FORMAT, TOPICS
from thintact_sdk.formats.mcap.writer import LogStats, McapLogWriter

__all__ = ["LOG_FORMAT", "TOPICS", "LogMessage", "LogStats", "McapLog", "McapLogWriter"]
