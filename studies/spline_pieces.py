"""A float64 probe (issue 44): does a B-spline support that glues separate pieces of material
stiffen the dragon? ``python -m studies.spline_pieces``.

Immersed B-spline methods give a control point one copy per connected piece of material in its
support, so that material which is not connected there (a leg beside the body, the tail over a
coil) does not share a degree of freedom (the finite cell method's answer to "topologically
distinct" supports; Schillinger & Ruess 2015, section 4.3; the same duplication as composite
hexahedra's, Nesme et al. 2009, section 4). This study builds that body from the scene's fill on
the same grid and solves the same static problem as :mod:`studies.spline_mesh_accuracy` (the held
band a penalty of 10^3 E / h^2 on the material in it), three ways:

* ``spans``: today's body (one piece per knot span, one copy per node);
* ``span pieces``: each knot span split into its connected pieces of material, one copy per node
  (the integration differs, the field does not);
* ``copies``: each knot span split into its pieces, and each node one copy per connected piece of
  material in its support (26-connected fill samples; pieces that connect outside the support
  still share their other control points).

Each mesh vertex is read through the piece of its knot span nearest to it. Ratios to the same FEM
references as docs/ACCURACY.md section 9, with the error by region (the vertices in fifths of the
mesh's height).
"""

from __future__ import annotations

import argparse
import time
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spl
from scipy import ndimage
from scipy.spatial import cKDTree

from deformgl.sim.terms.spline.basis import SPAN_OFFSETS, span_basis
from deformgl.sim.terms.spline.body import SplineBody
from deformgl.sim.terms.spline.cut import _control_grid, span_quadrature, span_samples
from studies.mesh_accuracy import (DENSITY, FEM_REFERENCE, G, HOLD, MESHES, POISSON, YOUNGS_MODULUS, fem_sag,
                                   repaired_mesh)

_CONNECT = ndimage.generate_binary_structure(3, 3)
#: a copy whose share of the material is under this (span units, h^3) stays with its node's largest
MIN_SHARE = 1e-5


@dataclass(frozen=True, eq=False)
class CopiedBody(SplineBody):
    """A spline body whose ``span_nodes`` number copies of the grid's nodes (``copy_node`` (C,):
    each copy's node)."""

    copy_node: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))

    @property
    def count(self) -> int:
        return len(self.copy_node)

    @property
    def rest_positions(self) -> np.ndarray:
        return self.grid.rest_positions[self.copy_node]


def piece_body(origin, spacing: float, samples: int, inside: np.ndarray, *, split_spans: bool, copies: bool,
               surface=None, connect: np.ndarray = _CONNECT):
    """The body of a fill (module docstring); also each sample piece's span piece and world centre.
    ``surface``: the fill's measured surface boxes (:mod:`deformgl.grid.line_fill`); ``connect``
    the samples' connectivity."""
    s = int(samples)
    centre, local_s, widths, index = span_samples(s, inside, surface)
    # each box's sample (a measured box whose centre is outside is its sample's too)
    sample = np.clip(np.floor((centre + local_s) * s).astype(np.int64), 0, np.array(inside.shape) - 1)
    inside = inside.copy()
    inside[tuple(sample.T)] = True
    where, index = sample, np.arange(len(sample))
    volume = np.prod(widths, axis=1)
    centres, span_of = np.unique(centre, axis=0, return_inverse=True)
    span_of = span_of.ravel()
    # each span's connected pieces of samples
    piece = np.zeros(len(centre), np.int64)
    if split_spans:
        order = np.argsort(span_of, kind="stable")
        starts = np.searchsorted(span_of[order], np.arange(len(centres) + 1))
        for c in range(len(centres)):
            rows = order[starts[c]:starts[c + 1]]
            ijk = where[index[rows]]
            lo = ijk.min(axis=0)
            block = np.zeros(tuple(ijk.max(axis=0) - lo + 1), bool)
            block[tuple((ijk - lo).T)] = True
            labels = ndimage.label(block, connect)[0]
            piece[rows] = labels[tuple((ijk - lo).T)] - 1
    keys, sp_of = np.unique(np.stack([span_of, piece], axis=1), axis=0, return_inverse=True)
    sp_of = sp_of.ravel()
    sp_span = keys[:, 0]
    point_span, point_s, point_w = span_quadrature(sp_of, len(keys), local_s, widths)
    grid, local_centres = _control_grid(np.asarray(origin, np.float64), spacing, centres)
    low = centres[0] - local_centres[0]  # the control grid's first node, global node index
    ijk = local_centres[sp_span][:, None, :] + SPAN_OFFSETS[None]
    grid_nodes = grid.index[ijk[..., 0], ijk[..., 1], ijk[..., 2]]  # (SP, 27)
    if copies:
        # every node's support: the samples within 3/2 spans of it, labelled into connected pieces
        representative = np.zeros(len(keys), np.int64)
        representative[sp_of[::-1]] = np.arange(len(sp_of))[::-1]
        rep_ijk = where[index[representative]]  # a sample of each span piece
        pairs_sp, pairs_k = np.nonzero(np.ones(grid_nodes.shape, bool))
        pair_node = grid_nodes[pairs_sp, pairs_k]
        by_node = np.argsort(pair_node, kind="stable")
        starts = np.searchsorted(pair_node[by_node], np.arange(grid.count + 1))
        label = np.zeros(len(pair_node), np.int64)
        node_ijk = grid.ijk + low
        for a in range(grid.count):
            rows = by_node[starts[a]:starts[a + 1]]
            if not len(rows):
                continue
            first = np.maximum(np.ceil((node_ijk[a] - 1.5) * s - 0.5 - 1e-9).astype(np.int64), 0)
            last = np.minimum(np.floor((node_ijk[a] + 1.5) * s - 0.5 + 1e-9).astype(np.int64) + 1, inside.shape)
            labels = ndimage.label(inside[first[0]:last[0], first[1]:last[1], first[2]:last[2]], connect)[0]
            at = rep_ijk[pairs_sp[rows]] - first
            label[rows] = labels[tuple(at.T)]
        assert np.all(label > 0)
        # a copy's share of the material: the volume of the span pieces it is a node of, weighted
        # by its basis function at their samples (its mass over rho); one under MIN_SHARE h^3 (a
        # sliver that would hold no stiffness) stays with the node's largest copy
        copy_keys, copy_of = np.unique(np.stack([pair_node, label], axis=1), axis=0, return_inverse=True)
        copy_of = copy_of.ravel()
        values = span_basis(local_s, 1.0)[0] * volume[:, None]  # (M, 27)
        share = np.bincount(copy_of, np.bincount(np.repeat(sp_of, 27) * 27 + np.tile(np.arange(27), len(sp_of)),
                                                 values.ravel(), minlength=27 * len(keys))
                            [pairs_sp * 27 + pairs_k], minlength=len(copy_keys))
        largest = np.zeros(grid.count, np.int64)
        best = np.full(grid.count, -1.0)
        for c in np.argsort(share):
            largest[copy_keys[c, 0]] = c
            best[copy_keys[c, 0]] = share[c]
        merged = np.where(share < MIN_SHARE, largest[copy_keys[:, 0]], np.arange(len(copy_keys)))
        kept, renumber = np.unique(merged, return_inverse=True)
        span_nodes = np.empty_like(grid_nodes)
        span_nodes[pairs_sp, pairs_k] = renumber.ravel()[copy_of]
        copy_node = copy_keys[kept, 0]
    else:
        span_nodes, copy_node = grid_nodes, np.arange(grid.count)
    point_w = point_w * spacing ** 3
    body = CopiedBody(grid, span_nodes, point_span, point_s, point_w, YOUNGS_MODULUS, POISSON,
                      DENSITY, "p1", copy_node)
    sample_world = np.asarray(origin) + (centre + local_s) * spacing
    return body, sp_of, sample_world, local_centres[sp_span]


def static_sag(mesh, nodes_along: int, *, split_spans: bool, copies: bool, measured: bool = False,
               connectivity: int = 26):
    """(mean, largest, top sag at the vertices (m), per-vertex sag, control points, span pieces)."""
    from deformgl.grid.fill import fill_cells

    vox, fill = fill_cells(mesh, nodes_along_longest=nodes_along)
    # the fill's largest connected piece (the dragon's fill at 32 along has a one-sample island,
    # which copies would set free)
    labels, count = ndimage.label(fill.inside, _CONNECT)
    inside = labels == 1 + int(np.argmax(np.bincount(labels.ravel())[1:])) if count > 1 else fill.inside
    surface = None
    if measured:
        from deformgl.grid.line_fill import surface_samples

        triangles = (np.asarray(mesh.triangles, np.float64) - vox.origin) / vox.spacing * fill.samples - 0.5
        surface = surface_samples(triangles, inside, fill.samples / 2.0)
    connect = ndimage.generate_binary_structure(3, 1 if connectivity == 6 else 3)
    body, sp_of, sample_world, sp_centre = piece_body(vox.origin, vox.spacing, fill.samples, inside,
                                                      split_spans=split_spans, copies=copies, surface=surface,
                                                      connect=connect)
    h = body.spacing
    k = body.assemble()
    # the held band: the material below HOLD of the mesh's height, a penalty of 10^3 E / h^2
    bounds = np.asarray(mesh.bounds, np.float64)
    centre_world = body.grid.origin + sp_centre[body.point_span] * h + body.point_s * h
    held = (centre_world[:, 1] < bounds[0, 1] + HOLD * (bounds[1, 1] - bounds[0, 1])) & (body.point_weight > 0)
    values = span_basis(body.point_s[held], h)[0]
    nodes = body.span_nodes[body.point_span[held]]
    penalty = 1e3 * YOUNGS_MODULUS / h ** 2 * body.point_weight[held]
    rows = np.repeat(nodes, 27, axis=1).ravel()
    cols = np.tile(nodes, (1, 27)).ravel()
    vals = (penalty[:, None, None] * values[:, :, None] * values[:, None, :]).ravel()
    n = body.count
    anchor = sp.coo_matrix((vals, (rows, cols)), shape=(n, n)).tocsr()
    k = k + sp.kron(anchor, sp.eye(3), format="csr")
    f = np.zeros((n, 3))
    f[:, 1] = -body.lumped_mass * G
    u = spl.spsolve(k.tocsc(), f.ravel()).reshape(-1, 3)
    # each vertex through the piece of its span nearest to it
    vertices = np.asarray(mesh.vertices, np.float64)
    t = (vertices - body.grid.origin) / h
    span_ijk = np.rint(t).astype(np.int64)
    tree = cKDTree(sample_world)
    _, near = tree.query(vertices, k=64)
    near_sp = sp_of[near]
    same = np.all(sp_centre[near_sp] == span_ijk[:, None, :], axis=2)
    pick = np.where(same.any(axis=1), near_sp[np.arange(len(near)), np.argmax(same, axis=1)], near_sp[:, 0])
    s = t - sp_centre[pick]
    sag = -np.einsum("va,va->v", span_basis(s, h)[0], u[body.span_nodes[pick], 1])
    top = int(np.argmax(vertices[:, 1]))
    return float(sag.mean()), float(sag.max()), float(sag[top]), sag, body.count, len(sp_centre)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m studies.spline_pieces", description=__doc__.split("\n\n")[0])
    parser.add_argument("--mesh", choices=sorted(MESHES), action="append", help="the meshes (default: dragon)")
    parser.add_argument("--nodes", default="12,16,24,32", help="nodes along the longest side, comma separated")
    parser.add_argument("--measured", action="store_true",
                        help="the fill's surface boxes measured against the mesh (the scene path's body)")
    parser.add_argument("--connectivity", type=int, choices=(6, 26), default=26,
                        help="samples that touch by a face (6) or by a face, edge or corner (26) are connected")
    args = parser.parse_args(argv)
    for name in args.mesh or ["dragon"]:
        mesh = repaired_mesh(name)
        fem = FEM_REFERENCE[name]
        ys = np.asarray(mesh.vertices)[:, 1]
        fifth = np.minimum(((ys - ys.min()) / np.ptp(ys) * 5).astype(int), 4)
        fem_vertex = fem_sag(mesh).vertex_sag  # the coarse level's, for the error by region
        assert fem_vertex is not None
        fem_bands = [float(fem_vertex[fifth == b].mean()) for b in range(5)]
        print(f"\n{name}: ratios to its FEM (P2, the refined level): mean, largest, top; by fifth of the height "
              f"(lowest first) to the coarse level's mean sag there ({', '.join(f'{b * 1e6:.2f}' for b in fem_bands)} um)")
        for n in (int(v) for v in args.nodes.split(",")):
            for label, split, copy in (("spans", False, False), ("span pieces", True, False), ("copies", True, True)):
                start = time.perf_counter()
                mean, largest, top, sag, count, pieces = static_sag(mesh, n, split_spans=split, copies=copy,
                                                                      measured=args.measured,
                                                                      connectivity=args.connectivity)
                print(f"  {n:>3} along, {label:<11}: {count:>6} control points, {pieces:>6} span pieces: mean "
                      f"{mean / fem[0]:.3f}, largest {largest / fem[1]:.3f}, top {top / fem[2]:.3f}"
                      f"  [{time.perf_counter() - start:.0f} s]", flush=True)
                bands = [float(sag[fifth == b].mean()) for b in range(5)]
                print("       by fifth of the height: " + ", ".join(f"{b / f:.3f}" for b, f in zip(bands, fem_bands)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
