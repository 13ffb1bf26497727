"""A run's output files committed together: all of them or none (filled in by issue 14)."""

from __future__ import annotations
