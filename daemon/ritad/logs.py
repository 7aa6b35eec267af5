"""Logging set-up: journald-friendly lines, and WARNING+ records mirrored on the bus (topic ``log``)."""
from __future__ import annotations

import logging
import os
import sys
from typing import Any, Callable

from daemon.bus.names import Topic

_PRIORITY = {logging.DEBUG: 7, logging.INFO: 6, logging.WARNING: 4, logging.ERROR: 3, logging.CRITICAL: 2}


class _JournalFormatter(logging.Formatter):
    """Prefix ``<N>`` so journald records the priority (systemd's SyslogLevelPrefix)."""

    def format(self, record: logging.LogRecord) -> str:
        return f"<{_PRIORITY.get(record.levelno, 6)}>{super().format(record)}"


def setup_logging(level: str = "INFO") -> None:
    handler = logging.StreamHandler(sys.stderr)
    if os.environ.get("JOURNAL_STREAM"):
        handler.setFormatter(_JournalFormatter("%(name)s: %(message)s"))
    else:
        handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(name)s: %(message)s"))
    root = logging.getLogger()
    root.handlers[:] = [handler]
    root.setLevel(level.upper())


class BusLogHandler(logging.Handler):
    """Publish WARNING and above on the telemetry bus so operators see them in ``ritactl watch``."""

    def __init__(self, publish: Callable[[str, Any], None], level: int = logging.WARNING) -> None:
        super().__init__(level)
        self._publish = publish

    def emit(self, record: logging.LogRecord) -> None:
        try:
            self._publish(Topic.LOG, {"level": record.levelname, "logger": record.name,
                                      "message": record.getMessage(), "t": record.created})
        except Exception:  # logging must never raise into the caller
            pass
