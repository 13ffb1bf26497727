"""The fields a spline body's frames export (``--export-mesh out.xdmf|.pvd|.vtu|.usd``,
``--export-grid``; issue 44, item 4): the body itself, not its control cage.

* **The body** (``--export-grid``): one hexahedron per knot span that holds material (the cube
  ``[X_c - h/2, X_c + h/2]`` of node c), its corners where the B-spline field puts them
  (``x(p) = sum_a N_a(p) x_a``: continuous across spans, so each corner is one point), with
  ``displacement`` and ``velocity`` (the field of the control points' velocities) at the corners,
  and per span the field's ``volume_ratio`` J = det F and Green–Lagrange strain
  ``E = (FᵀF − I)/2`` at its centre (``F = sum_a x_a ⊗ ∇N_a``) and ``fill``, the share of the span
  the material fills.
* **The detailed mesh** (``--export-mesh`` as a time series): the vertices as drawn (the field at
  their rest positions), ``displacement``, ``velocity`` (the field of the velocities: the field is
  linear in the control points, so this is the vertices' own velocity), and the field's
  ``volume_ratio`` and ``green_strain`` at each vertex.

World coordinates in m (the scene's recentring undone), SI units.
"""

from __future__ import annotations

import numpy as np

from deformgl.render.bspline_premap import vertex_spans
from deformgl.scene.fields import VTK_HEXAHEDRON, green_strain, time_scale
from deformgl.sim.terms.spline.basis import span_basis
from deformgl.sim.terms.spline.body import SplineBody

__all__ = ["body_series", "span_hexahedra", "spline_mesh_series"]

#: the 8 corners of a span in deformgl's corner numbering (c = dx + 2 dy + 4 dz), span coordinates
_CORNERS = np.array([(dx, dy, dz) for dz in (0, 1) for dy in (0, 1) for dx in (0, 1)], np.float64) - 0.5


def span_hexahedra(body: SplineBody) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The body's spans as hexahedra: (S, 8) point numbers (deformgl's corner order), the points'
    rest positions (P, 3), m, and for each point a (span, corner) it is a corner of (P, 2)."""
    doubled = 2 * body.grid.ijk[body.span_nodes[:, 13]][:, None, :] + (2 * _CORNERS).astype(np.int64)[None]
    keys, first, inverse = np.unique(doubled.reshape(-1, 3), axis=0, return_index=True, return_inverse=True)
    rest = body.grid.origin + keys * (body.spacing / 2.0)
    return inverse.reshape(-1, 8), rest, np.stack([first // 8, first % 8], axis=1)


def _corner_field(body: SplineBody, owner: np.ndarray, values: np.ndarray) -> np.ndarray:
    """(P, 3) the field of node ``values`` (N, 3) at the corners ``owner`` (P, 2) name."""
    basis = span_basis(_CORNERS, body.spacing)[0]  # (8, 27): the same in every span
    return np.einsum("pa,pad->pd", basis[owner[:, 1]], values[body.span_nodes[owner[:, 0]]])


def span_gradients(body: SplineBody, x: np.ndarray) -> np.ndarray:
    """(S, 3, 3) the field's deformation gradient at each span's centre for control points ``x``."""
    gradients = span_basis(np.zeros(3), body.spacing)[1]  # (27, 3)
    return np.einsum("sai,aj->sij", x[body.span_nodes], gradients)


def body_series(frames, fps: float):
    """The :class:`~deformgl.scene.interchange.Series` of a spline body's frames (the module
    docstring; :class:`~deformgl.scene.animation.Frames` rendered with ``nodes=True``)."""
    from deformgl.scene.interchange import Series

    built = frames.model
    body: SplineBody = built.spline
    cells, rest, owner = span_hexahedra(body)
    fill = body.span_volume / body.spacing ** 3
    points, point_data, cell_data = [], [], []
    for sample in frames.nodes:
        x = np.asarray(sample.x, np.float64)
        at = _corner_field(body, owner, x)
        points.append(at + built.centre)
        data = {"displacement": at - rest}
        if sample.v is not None:
            data["velocity"] = _corner_field(body, owner, np.asarray(sample.v, np.float64))
        point_data.append(data)
        f = span_gradients(body, x)
        cell_data.append({"volume_ratio": np.linalg.det(f), "green_strain": green_strain(f).reshape(-1, 9),
                          "fill": fill})
    return Series("hexahedron", cells[:, list(VTK_HEXAHEDRON)], rest + built.centre,
                  [s.time_s for s in frames.nodes], points, point_data, cell_data, fps=fps)


def spline_mesh_series(frames, fps: float):
    """The :class:`~deformgl.scene.interchange.Series` of the detailed mesh drawn through a spline
    body (the module docstring), from frames rendered with ``nodes=True`` and ``mesh=True``."""
    from deformgl.scene.interchange import Series

    built = frames.model
    body: SplineBody = built.spline
    rest = np.asarray(built.mesh.vertices, np.float64)
    nodes, s = vertex_spans(body, rest)
    values, gradients = span_basis(s, body.spacing)
    vertices, normals, data = [], [], []
    for (v, n, _), sample in zip(frames.meshes, frames.nodes):
        v = np.asarray(v, np.float64)
        vertices.append(v)
        length = np.linalg.norm(n, axis=1, keepdims=True)
        normals.append(np.asarray(n, np.float64) / np.where(length > 0, length, 1.0))
        f = np.einsum("vai,vaj->vij", np.asarray(sample.x, np.float64)[nodes], gradients)
        d = {"displacement": v - (rest + built.centre), "volume_ratio": np.linalg.det(f),
             "green_strain": green_strain(f).reshape(-1, 9)}
        if sample.v is not None:
            d["velocity"] = np.einsum("va,vad->vd", values, np.asarray(sample.v, np.float64)[nodes])
        data.append(d)
    return Series("triangle", np.asarray(built.mesh.faces), rest + built.centre, [s.time_s for s in frames.nodes],
                  vertices, data, normals=normals, fps=fps, time_scale=time_scale(frames, fps))
