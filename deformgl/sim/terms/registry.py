"""The physics terms deformgl ships, as their GLSL forms (:class:`~deformgl.sim.terms.base.GlslTerm`):
what the shader pack enumerates and compiles (``shaders/terms/active.glsl`` is :func:`shipped_active`,
each term under ``#ifdef TERM_<PREFIX>``). A new shipped term adds its form here.

``python -m deformgl.sim.terms.registry`` writes ``shaders/terms/active.glsl`` from this list
(tests/test_terms.py checks the shipped file is the list's)."""

from __future__ import annotations

import sys
from pathlib import Path

from deformgl.sim import bending, volume_glsl
from deformgl.sim.terms.base import GlslTerm
from deformgl.sim.terms.glsl import compose

__all__ = ["SHIPPED", "VARIANTS", "shipped_active"]

#: The GLSL forms of the shipped terms, in the order a system's terms are summed.
SHIPPED: tuple[GlslTerm, ...] = (volume_glsl.GLSL, bending.GLSL)
#: Every form of each, as the shader pack enumerates them.
VARIANTS: tuple[GlslTerm, ...] = (*volume_glsl.CELL_FORMS, bending.GLSL)


def shipped_active() -> str:
    """The text of ``shaders/terms/active.glsl``: every shipped term, each under its define."""
    return compose(SHIPPED, guarded=True)


def main() -> int:
    """Write ``shaders/terms/active.glsl`` of the repository (or of the path given)."""
    path = Path(sys.argv[1]) if len(sys.argv) > 1 else Path(__file__).resolve().parents[3] / "shaders" / "terms" / "active.glsl"
    path.write_text(shipped_active(), encoding="utf-8")
    print(path)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
