"""Warnings that repeat at most once a minute per key (no Zenoh, no services: the run log's
writer uses it as well as every service)."""

from __future__ import annotations

import logging
import threading
import time


class WarnOncePerMinute:
    """Logs a warning once per key per minute, counting the ones it held back."""

    def __init__(self, logger: logging.Logger, period_s: float = 60.0) -> None:
        self._log = logger
        self._period = period_s
        self._last: dict[str, float] = {}
        self._held: dict[str, int] = {}
        self._lock = threading.Lock()

    def warn(self, key: str, message: str) -> None:
        now = time.monotonic()
        with self._lock:
            last = self._last.get(key)
            if last is not None and now - last < self._period:
                self._held[key] = self._held.get(key, 0) + 1
                return
            held = self._held.pop(key, 0)
            self._last[key] = now
        suffix = f" ({held} more like it in the last minute)" if held else ""
        self._log.warning("%s%s", message, suffix)
