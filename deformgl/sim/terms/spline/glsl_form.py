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
from deformgl.sim.terms.spline.tables import span_tables

__all__ = ["GLSL", "SAMPLERS", "spline_glsl"]

#: The samplers of the span pass's outputs in the chunk.
SAMPLERS = ("u_spline_f0", "u_spline_f1", "u_spline_f2", "u_spline_f3")
#: The term's GLSL form without its data (the shader pack's; :func:`spline_glsl` gives a body's).
GLSL = GlslTerm("spline", file="terms/spline.glsl", passes=("terms/spline_span.frag",))


def spline_glsl(body: SplineBody) -> GlslTerm:
    """:data:`GLSL` with ``body``'s node table, its row uniform and its span pass."""
    from deformgl.sim.terms.spline import span_pass  # (GL: imported where a GPU backend builds it)

    tables = span_tables(body)
    return dataclasses.replace(GLSL, tables=(NodeTable("u_spline_spans", tables.node_spans),),
                               uniforms={"u_spline_row": tables.row},
                               prepass=functools.partial(span_pass.SplineSpanPass, tables=tables),
                               prepass_samplers=SAMPLERS)
