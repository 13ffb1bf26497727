"""The physics terms deformgl ships, as their GLSL forms (:class:`~deformgl.sim.terms.base.GlslTerm`),
transform-feedback chunks (:class:`~deformgl.sim.terms.base.FeedbackTerm`) and XPBD chunks
(:class:`~deformgl.sim.terms.constraints.XpbdChunk`): what the shader pack enumerates and compiles
(``shaders/terms/active.glsl`` is :func:`shipped_active`, ``shaders/terms/feedback.glsl``
:func:`shipped_feedback`, ``shaders/terms/xpbd.glsl`` :func:`shipped_xpbd`, each term under
``#ifdef TERM_<PREFIX>``). A new shipped term adds its forms here.

``python -m deformgl.sim.terms.registry`` writes the three files from these lists (tests/test_terms.py
checks the shipped files are the lists')."""

from __future__ import annotations

import sys
from pathlib import Path

from deformgl.sim.terms import bending
from deformgl.sim.terms.spline import glsl_form as spline_form
from deformgl.sim.terms.volume import chunks as volume_chunks, xpbd_form as volume_xpbd
from deformgl.sim.terms.base import FeedbackTerm, GlslTerm
from deformgl.sim.terms.constraints import XpbdChunk
from deformgl.sim.terms.glsl import ACTIVE, FEEDBACK, XPBD, compose, compose_feedback, compose_xpbd

__all__ = ["FEEDBACK_SHIPPED", "SHIPPED", "TOGETHER", "VARIANTS", "XPBD_SHIPPED", "shipped_active", "shipped_feedback",
           "shipped_xpbd"]

#: The GLSL forms of the shipped terms, in the order a system's terms are summed.
SHIPPED: tuple[GlslTerm, ...] = (volume_chunks.GLSL, bending.GLSL, spline_form.GLSL, spline_form.ANCHOR_GLSL)
#: Every form of each, as the shader pack enumerates them.
VARIANTS: tuple[GlslTerm, ...] = (*volume_chunks.CELL_FORMS, bending.GLSL, spline_form.GLSL, spline_form.ANCHOR_GLSL)
#: Forms a system holds together (a spline body and its held regions), which the shader pack also
#: compiles as one set.
TOGETHER: tuple[tuple[GlslTerm, ...], ...] = ((spline_form.GLSL, spline_form.ANCHOR_GLSL),)
#: The transform-feedback chunks of the shipped terms that have one (the rest give
#: ``Term.feedback_pairs`` or are refused).
FEEDBACK_SHIPPED: tuple[FeedbackTerm, ...] = (volume_chunks.FEEDBACK,)
#: The XPBD node-sweep chunks of the shipped terms that have one, each with its define variants.
XPBD_SHIPPED: tuple[XpbdChunk, ...] = (volume_xpbd.XPBD,)


def shipped_active() -> str:
    """The text of ``shaders/terms/active.glsl``: every shipped term, each under its define."""
    return compose(SHIPPED, guarded=True)


def shipped_feedback() -> str:
    """The text of ``shaders/terms/feedback.glsl``: every shipped feedback chunk, each under its define."""
    return compose_feedback(FEEDBACK_SHIPPED, guarded=True)


def shipped_xpbd() -> str:
    """The text of ``shaders/terms/xpbd.glsl``: every shipped XPBD chunk, each under its define."""
    return compose_xpbd(XPBD_SHIPPED, guarded=True)


def main() -> int:
    """Write ``terms/active.glsl``, ``terms/feedback.glsl`` and ``terms/xpbd.glsl`` under the
    repository's ``shaders/`` (or under the folder given)."""
    root = Path(sys.argv[1]) if len(sys.argv) > 1 else Path(__file__).resolve().parents[3] / "shaders"
    for name, text in ((ACTIVE, shipped_active()), (FEEDBACK, shipped_feedback()), (XPBD, shipped_xpbd())):
        (root / name).parent.mkdir(parents=True, exist_ok=True)
        (root / name).write_text(text, encoding="utf-8")
        print(root / name)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
