"""Bounded readers of user input files (filled in by issue 14)."""

from __future__ import annotations
