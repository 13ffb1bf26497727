"""The spline cells' span tables: what the span pass (``shaders/terms/spline_span.frag``) reads
per knot span and what the gather (``shaders/terms/spline.glsl``) reads per node, built from a
:class:`~deformgl.sim.terms.spline.body.SplineBody` (no GL here). The channel layouts are
documented once, in those two shader files."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from deformgl.sim.terms.spline.body import SplineBody

__all__ = ["SPAN_DATA_TEXELS", "SPAN_GROUPS", "SPAN_NODE_TEXELS", "SpanTables", "span_tables"]

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
    """A body's span tables (the channel layouts: ``shaders/terms/spline_span.frag``).

    Attributes:
        nodes: (S, 28) int32 each span's 27 node numbers and a pad.
        data: (S, 72) float32 each span's Gauss points, weights, centroid and projection.
        node_spans: (N, 28) float32 per node and slot a the span whose node a it is, -1 none.
        row: spans per row of the span textures.
        mu, kappa: the shear and bulk moduli, Pa; spacing: h, m.
    """

    nodes: np.ndarray
    data: np.ndarray
    node_spans: np.ndarray
    row: int
    mu: float
    kappa: float
    spacing: float

    @property
    def spans(self) -> int:
        return int(len(self.nodes))


def span_tables(body: SplineBody) -> SpanTables:
    """The span tables of ``body``.

    Raises:
        ValueError: a span whose material is not one 3 x 3 x 3 grid of Gauss points (a span of
            :meth:`SplineBody.from_inside` cut by the surface holds a grid per sub-box).
    """
    count = len(body.span_nodes)
    per_span = np.bincount(body.point_span, minlength=count)
    if np.any(per_span != 27):
        bad = int(np.argmax(per_span != 27))
        raise ValueError(f"spline cells: span {bad} (of node {body.grid.ijk[body.span_nodes[bad, 13]].tolist()}) holds "
                         f"{per_span[bad]} Gauss points; the GLSL form takes one 3 x 3 x 3 grid a span "
                         f"(SplineBody.moment_fitted() gives one)")
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
    nodes = np.zeros((count, 28), np.int32)
    nodes[:, :27] = body.span_nodes
    node_spans = np.full((body.count, 28), -1.0)
    node_spans[body.span_nodes, np.arange(27)[None, :]] = np.arange(count)[:, None]
    mu, kappa = body.moduli
    return SpanTables(nodes=nodes, data=data.astype(np.float32), node_spans=node_spans.astype(np.float32),
                      row=max(1, math.ceil(math.sqrt(count))), mu=float(mu), kappa=float(kappa),
                      spacing=body.spacing)
