"""The spline terms' span tables: what a span pass reads per knot span (the cells':
``shaders/terms/spline_span.frag``; a penalty anchor's: ``shaders/terms/spline_anchor.frag``) and
what its gather reads per node (``shaders/terms/spline.glsl``, ``shaders/terms/spline_anchor.glsl``),
built from a :class:`~deformgl.sim.terms.spline.body.SplineBody` (no GL here). The channel layouts
are documented once, in those shader files."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from deformgl.sim.terms.spline.body import SplineBody

__all__ = ["SPAN_DATA_TEXELS", "SPAN_GROUPS", "SPAN_NODE_TEXELS", "SpanTables", "anchor_tables", "span_tables"]

#: Fragments per span in the span pass (4 of its 27 nodes each: 4 render targets, the least a
#: GL 3.3 or OpenGL ES 3.0 context has).
SPAN_GROUPS = 7
#: RGBA32F texels per span of the span data.
SPAN_DATA_TEXELS = 18
#: RGBA32I texels per span of its node numbers.
SPAN_NODE_TEXELS = 7
_FUNCTIONS = {"full": 0, "p0": 1, "p1": 4}


@dataclass(frozen=True, eq=False)
class SpanTables:
    """What a span pass reads (``fragment``: its shader; the channel layouts are in it) and what its
    gather reads per node.

    Attributes:
        fragment: the span pass's fragment shader, under ``shaders/``.
        nodes: (S, 28) int32 each span's 27 node numbers and a pad.
        data: (S, 4 * data_texels) float32 each span's data.
        node_spans: (N, 28) float32 per node and slot a the span whose node a it is, -1 none.
        row: spans per row of the span textures.
        uniforms: the pass's own uniforms (material constants, h in m, ...).
    """

    fragment: str
    nodes: np.ndarray
    data: np.ndarray
    node_spans: np.ndarray
    row: int
    uniforms: dict[str, object]

    @property
    def spans(self) -> int:
        return int(len(self.nodes))

    @property
    def data_texels(self) -> int:
        """RGBA32F texels of data a span."""
        return int(self.data.shape[1] // 4)


def _node_spans(span_nodes: np.ndarray, count: int) -> np.ndarray:
    """(N, 28) float32: per node and slot a the span whose node a it is, -1 none."""
    out = np.full((count, 28), -1.0, np.float32)
    out[span_nodes, np.arange(27)[None, :]] = np.arange(len(span_nodes))[:, None]
    return out


def _padded(span_nodes: np.ndarray) -> np.ndarray:
    nodes = np.zeros((len(span_nodes), 28), np.int32)
    nodes[:, :27] = span_nodes
    return nodes


def _row(count: int) -> int:
    return max(1, math.ceil(math.sqrt(count)))


def span_tables(body: SplineBody) -> SpanTables:
    """The span tables of ``body``.

    Raises:
        ValueError: a span whose material is not one 3 x 3 x 3 grid of Gauss points (a span of
            :func:`~deformgl.sim.terms.spline.cut.inside_body` cut by the surface holds a grid per sub-box).
    """
    count = len(body.span_nodes)
    per_span = np.bincount(body.point_span, minlength=count)
    if np.any(per_span != 27):
        bad = int(np.argmax(per_span != 27))
        raise ValueError(f"spline cells: span {bad} (of node {body.grid.ijk[body.span_nodes[bad, 13]].tolist()}) holds "
                         f"{per_span[bad]} Gauss points; the GLSL form takes one 3 x 3 x 3 grid a span "
                         f"(deformgl.sim.terms.spline.cut.fitted_body gives one)")
    points = body.point_s.reshape(count, 3, 3, 3, 3)
    axes = np.stack([points[:, :, 0, 0, 0], points[:, 0, :, 0, 1], points[:, 0, 0, :, 2]], axis=1)  # (S, 3, 3)
    grid = np.stack(np.meshgrid(np.arange(3), np.arange(3), np.arange(3), indexing="ij"), axis=-1)
    tensor = np.stack([axes[:, 0][:, grid[..., 0]], axes[:, 1][:, grid[..., 1]], axes[:, 2][:, grid[..., 2]]], axis=-1)
    if not np.allclose(tensor, points, rtol=0.0, atol=1e-12):
        raise ValueError("spline cells: a span's Gauss points are not a tensor grid; the GLSL form takes one "
                         "3 x 3 x 3 grid a span")
    data = np.zeros((count, 4 * SPAN_DATA_TEXELS))
    for d in range(3):
        data[:, 4 * d: 4 * d + 3] = axes[:, d]
        data[:, 60 + 4 * d: 60 + 4 * d + 3] = axes[:, d] - body.span_centroids[:, d: d + 1]
    data[:, 12:39] = body.point_weight.reshape(count, 27)
    data[:, 40:43] = body.span_centroids
    functions = _FUNCTIONS[body.dilatation]
    data[:, 43] = functions
    if functions:
        inverse = body._projection[1]  # (S, P, P)
        for k in range(functions):
            data[:, 44 + 4 * k: 44 + 4 * k + functions] = inverse[:, k]
    mu, kappa = body.moduli
    return SpanTables(fragment="terms/spline_span.frag", nodes=_padded(body.span_nodes), data=data.astype(np.float32),
                      node_spans=_node_spans(body.span_nodes, body.count), row=_row(count),
                      uniforms={"u_h": body.spacing, "u_mu": float(mu), "u_kappa": float(kappa)})


def anchor_tables(body: SplineBody, points: np.ndarray, weights: np.ndarray) -> SpanTables:
    """The span tables of a penalty on ``body``'s field at quadrature ``points`` (P, 3), m, with
    ``weights`` (P,) times the penalty's stiffness (N/m each): the knot spans that hold a point
    (the span :meth:`SplineBody.locate` gives it, as the float64 term sums it), each with its
    points (``shaders/terms/spline_anchor.frag``: texel 0 the span centre's rest position, m, and
    its point count; then one texel a point, its span coordinates and weight)."""
    nodes, _, _ = body.locate(points)
    centres, span_of = np.unique(nodes[:, 13], return_inverse=True)
    first = np.zeros(len(centres), np.int64)
    first[span_of[::-1]] = np.arange(len(points))[::-1]
    span_nodes = nodes[first]
    counts = np.bincount(span_of, minlength=len(centres))
    order = np.argsort(span_of, kind="stable")
    slot = np.arange(len(points)) - np.repeat(np.cumsum(counts) - counts, counts)
    texels = 1 + int(counts.max())
    data = np.zeros((len(centres), texels, 4))
    data[:, 0, :3] = body.rest_positions[centres]
    data[:, 0, 3] = counts
    s = (points - body.rest_positions[nodes[:, 13]]) / body.spacing
    data[span_of[order], 1 + slot, :3] = s[order]
    data[span_of[order], 1 + slot, 3] = weights[order]
    return SpanTables(fragment="terms/spline_anchor.frag", nodes=_padded(span_nodes),
                      data=data.reshape(len(centres), 4 * texels).astype(np.float32),
                      node_spans=_node_spans(span_nodes, body.count), row=_row(len(centres)),
                      uniforms={"u_h": body.spacing, "u_span_texels": texels})
