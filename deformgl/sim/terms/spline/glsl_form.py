"""The spline cells' GLSL form: their chunk, its node table and their span pass (the tables:
:mod:`deformgl.sim.terms.spline.tables`; the pass, GL: :mod:`deformgl.sim.terms.spline.span_pass`).

The force of a node is a sum over the up to 27 knot spans whose node it is, each span's share
needing the span's rotation and its 27 Gauss points' stresses: work shared by the span's 27
nodes. So the term runs a pass of its own per force evaluation (``shaders/terms/spline_span.frag``:
each span's forces on its nodes, in 7 fragments of 4 nodes) and its chunk
(``shaders/terms/spline.glsl``) gathers a node's 27 shares. The channel layouts of the tables are
documented once, in ``shaders/terms/spline_span.frag`` (the span tables) and
``shaders/terms/spline.glsl`` (the node table).
"""

from __future__ import annotations

import dataclasses
import functools

from deformgl.sim.terms.base import GlslTerm, NodeTable
from deformgl.sim.terms.spline.body import SplineBody
from deformgl.sim.terms.spline.tables import SpanTables, anchor_tables, span_tables

__all__ = ["ANCHOR_GLSL", "GLSL", "anchor_glsl", "spline_glsl"]

#: The term's GLSL form without its data (the shader pack's; :func:`spline_glsl` gives a body's).
GLSL = GlslTerm("spline", file="terms/spline.glsl", passes=("terms/spline_span.frag",))
#: A penalty anchor's form without its data (its chunk gathers what its span pass computes).
ANCHOR_GLSL = GlslTerm("spline_anchor", file="terms/spline_anchor.glsl", passes=("terms/spline_anchor.frag",))


def _with_pass(form: GlslTerm, tables: SpanTables) -> GlslTerm:
    """``form`` with ``tables``' node table, its row uniform and its span pass."""
    from deformgl.sim.terms.spline import span_pass  # (GL: imported where a GPU backend builds it)

    p = form.prefix
    return dataclasses.replace(form, tables=(NodeTable(f"u_{p}_spans", tables.node_spans),),
                               uniforms={f"u_{p}_row": tables.row},
                               prepass=functools.partial(span_pass.SplineSpanPass, tables=tables),
                               prepass_samplers=tuple(f"u_{p}_f{c}" for c in range(4)))


def spline_glsl(body: SplineBody) -> GlslTerm:
    """:data:`GLSL` with ``body``'s node table, its row uniform and its span pass."""
    return _with_pass(GLSL, span_tables(body))


def anchor_glsl(body: SplineBody, points, weights) -> GlslTerm:
    """:data:`ANCHOR_GLSL` of a penalty at ``points`` (P, 3), m, with ``weights`` (P,) times its
    stiffness, N/m."""
    return _with_pass(ANCHOR_GLSL, anchor_tables(body, points, weights))
