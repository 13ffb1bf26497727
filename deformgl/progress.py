"""A minimal progress bar on stderr that appears only for runs longer than ``delay`` seconds."""

from __future__ import annotations

import sys
import time
from typing import TextIO


class Progress:
    """``with Progress(total, "steps") as p: p.update(k)``; silent when ``enabled`` is False."""

    def __init__(self, total: int, unit: str, *, enabled: bool = True, delay: float = 1.0,
                 stream: TextIO | None = None) -> None:
        self.total, self.unit, self.enabled, self.delay = max(total, 1), unit, enabled, delay
        self.stream = stream or sys.stderr
        self.start = time.perf_counter()
        self.shown = False

    def update(self, done: int) -> None:
        """Report ``done`` of ``total``; draws once the delay has passed."""
        if not self.enabled or time.perf_counter() - self.start < self.delay:
            return
        width = 30
        filled = int(width * done / self.total)
        elapsed = time.perf_counter() - self.start
        self.stream.write(f"\r[{'#' * filled}{'.' * (width - filled)}] {done}/{self.total} "
                          f"{self.unit} {elapsed:5.1f} s")
        self.stream.flush()
        self.shown = True

    def __enter__(self) -> "Progress":
        return self

    def __exit__(self, *exc: object) -> None:
        if self.shown:
            self.stream.write("\n")
            self.stream.flush()
